"""The printer model: G-code dispatch, planner, thermal model. Knows no wire format."""
