"""Coverage-guided fuzzing of every receiver of untrusted bytes (see fuzz/README.md)."""
