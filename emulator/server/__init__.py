"""The printer on a link: power, resets, sessions, faults; and the clock it runs on."""
