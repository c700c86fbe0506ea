"""Sans-IO cores of the host: per protocol, what to send when, and what an answer means."""
