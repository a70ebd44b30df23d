"""Data-consistency checks of a track against its ground truth (``nespm check``)."""
