"""fake-marlin: a virtual Marlin printer on a pseudo-terminal."""
