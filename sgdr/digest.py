"""Content digests: of a config key (`key_hash`, over its JSON-able form `plain`) and of a file
(`file_hash`). The stage cache and the run folders' sequence digests use them."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, ListConfig, OmegaConf


def key_hash(key: Any) -> str:
    """SHA-256 of a JSON-able description of a stage's config and inputs (sorted keys)."""
    text = json.dumps(plain(key), sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def plain(x: Any) -> Any:
    """A JSON-able copy of a key: dataclasses and DictConfigs as dicts, arrays as digests."""
    if is_dataclass(x) and not isinstance(x, type):
        return asdict(x)
    if isinstance(x, (DictConfig, ListConfig)):
        return OmegaConf.to_container(x, resolve=True)
    if isinstance(x, Mapping):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest() + str(x.shape)
    if isinstance(x, Path):
        return str(x)
    return x


def file_hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
