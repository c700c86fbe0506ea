"""The fault layer between link and protocol: rules, triggers, and the damage they do."""
