"""Sequence formats: sgdr's own folder layout, and readers for the Spring-Gaus and PAC-NeRF layouts.

`load_sequence(path)` auto-detects the layout and returns a `Sequence`; the pipeline reads
data only through it. `write_sequence(...)` writes sgdr's layout (used by the generator).
"""

from sgdr.data.layouts import load_sequence
from sgdr.data.sequence import Sequence, SequenceError, write_sequence

__all__ = ["Sequence", "SequenceError", "load_sequence", "write_sequence"]
