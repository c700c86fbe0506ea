"""The journal of executed commands, and checking it against a job."""
