"""`load_sequence`: which layout a sequence folder has, and the reader for it.

Layouts (a `sgdr.registry.Registry`, name -> (marker file, reader)):
- `sgdr`: `sequence.json` (`sgdr.data.sequence`, sgdr's own format)
- `spring_gaus`: `camera.json` (`sgdr.data.foreign`)
- `pac_nerf`: `all_data.json` (`sgdr.data.foreign`)

This module sits above `sequence` and `foreign` (foreign builds on sequence's helpers; neither
imports this one), so the two readers do not import each other.
"""

from __future__ import annotations

from pathlib import Path

from sgdr.data import foreign
from sgdr.data.sequence import SEQUENCE_FILE, Sequence, SequenceError, read_sgdr
from sgdr.registry import Registry


def _read_sgdr(root: Path, **scene_defaults) -> Sequence:
    return read_sgdr(root)  # sgdr's layout stores its scene: the defaults do not apply


LAYOUTS = Registry(
    "sequence layout",
    "sequence",
    SequenceError,
    {
        "sgdr": (SEQUENCE_FILE, _read_sgdr),
        "spring_gaus": (foreign.SPRING_GAUS_FILE, foreign.read_spring_gaus),
        "pac_nerf": (foreign.PAC_NERF_FILE, foreign.read_pac_nerf),
    },
)
_LAYOUT_TITLES = {"sgdr": "sgdr", "spring_gaus": "Spring-Gaus", "pac_nerf": "PAC-NeRF"}


def detect_layout(root: Path) -> str:
    """The name of the first layout whose marker file is in `root` (in `LAYOUTS` order)."""
    for name, (marker, _) in LAYOUTS.items():
        if (Path(root) / marker).is_file():
            return name
    expected = ", ".join(f"{marker} ({_LAYOUT_TITLES[name]})" for name, (marker, _) in LAYOUTS.items())
    raise SequenceError(f"{root}: no sequence found: expected {expected}")


def load_sequence(path, **scene_defaults) -> Sequence:
    """Read a sequence folder, auto-detecting the sgdr / Spring-Gaus / PAC-NeRF layout.

    scene_defaults: for the foreign layouts, which lack scene data, values for fps, n_fit,
      hit_frame, ground (dict with point and normal) and gravity; a `sgdr_scene.json` in the
      folder takes precedence over them (see `sgdr.data.foreign`). Ignored for sgdr's layout.
    """
    root = Path(path)
    if not root.is_dir():
        raise SequenceError(f"{root}: sequence folder does not exist")
    _, reader = LAYOUTS.get_named(detect_layout(root))
    return reader(root, **scene_defaults)
