"""Links between the printer and its host: how bytes travel, nothing about what they mean."""
