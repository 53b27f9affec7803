"""Relational-map files: named ATs between frames, in JSON or YAML (loaded safely).

Format (version 1)::

    relmap: 1                 # optional format version
    description: free text    # optional
    angle_unit: deg           # "rad" (default) or "deg": applies to θ, σθ and θ rows of cov
    ats:
      - {name: A, from: W, to: L1, mean: [2.0, 0.5, 60.0], sigma: [0.06, 0.04, 2.0]}
      - name: S
        from: L4
        to: W
        mean: [0.52, -1.60, 44.0]
        cov: [[9e-4, 0, 0], [0, 9e-4, 0], [0, 0, 1.0]]

Each AT says where frame ``to`` is, seen from frame ``from``: ``mean`` is ``(x, y, θ)``, the
uncertainty is ``sigma`` (independent standard deviations), ``cov`` (3×3 on ``(x, y, θ)`` in the
``from`` frame), or neither (exactly known). Names must be unique. Unknown keys are errors, so a
typo never passes silently. Errors name the file and the entry.

3-D maps give ``mean: [x, y, z, qx, qy, qz, qw]`` (scalar-last unit quaternion), ``sigma`` of
``(x, y, z, φx, φy, φz)`` and a 6×6 ``cov`` in relmap's convention (translation in the ``from``
frame, rotation applied on the left; :class:`relmap.AT3`); ``angle_unit: deg`` then scales the
rotation rows of ``sigma``/``cov`` (never the quaternion). A file holds one kind or the other.
"""

from __future__ import annotations

import json
import os
from collections.abc import Hashable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from relmap.at import AT
from relmap.at3 import AT3
from relmap.errors import FileFormatError, RelmapError
from relmap.io.atomic import write_text_atomic

__all__ = ["ATRecord", "read_records", "write_records"]

FORMAT_VERSION = 1
_ENTRY_KEYS = {"name", "from", "to", "mean", "sigma", "cov"}
_TOP_KEYS = {"relmap", "description", "angle_unit", "ats"}


class ATRecord(NamedTuple):
    """One AT of a map file: ``at`` says where frame ``dst`` is, seen from frame ``src``."""

    name: str
    src: Hashable
    dst: Hashable
    at: AT | AT3


def _parse(path: Path, text: str) -> Any:
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise FileFormatError(path, f"invalid JSON: {exc.msg}", line=exc.lineno) from None
    import yaml  # lazy: only map files need it

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise FileFormatError(
            path, f"invalid YAML: {getattr(exc, 'problem', exc)}", line=line
        ) from None


def read_records(path: str | os.PathLike[str]) -> list[ATRecord]:
    """Read a map file (``.json``, or YAML for any other suffix) into :class:`ATRecord` s."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(p, f"cannot read: {exc.strerror}") from None
    doc = _parse(p, text)
    if not isinstance(doc, dict):
        raise FileFormatError(p, "expected a mapping with an 'ats' list at the top level")
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise FileFormatError(p, f"unknown top-level key(s) {sorted(map(str, unknown))}")
    version = doc.get("relmap", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise FileFormatError(
            p, f"unsupported format version {version!r} (this relmap reads {FORMAT_VERSION})"
        )
    unit = doc.get("angle_unit", "rad")
    if unit not in ("rad", "deg"):
        raise FileFormatError(p, f"angle_unit must be 'rad' or 'deg'; got {unit!r}")
    to_rad = np.pi / 180.0 if unit == "deg" else 1.0
    scale = np.array([1.0, 1.0, to_rad])
    scale3 = np.array([1.0, 1.0, 1.0, to_rad, to_rad, to_rad])
    entries = doc.get("ats")
    if not isinstance(entries, list):
        raise FileFormatError(p, "'ats' must be a list of AT entries")
    records: list[ATRecord] = []
    seen: set[str] = set()
    for i, entry in enumerate(entries):
        where = f"ats[{i}]"
        if not isinstance(entry, dict):
            raise FileFormatError(p, f"{where} must be a mapping")
        name = str(entry.get("name", f"e{i}"))
        where = f"ats[{i}] ({name!r})"
        if name in seen:
            raise FileFormatError(p, f"{where}: duplicate AT name")
        seen.add(name)
        unknown = set(entry) - _ENTRY_KEYS
        if unknown:
            raise FileFormatError(p, f"{where}: unknown key(s) {sorted(map(str, unknown))}")
        for key in ("from", "to", "mean"):
            if key not in entry:
                raise FileFormatError(p, f"{where}: missing '{key}'")
        for key in ("from", "to"):
            if not isinstance(entry[key], (str, int)) or isinstance(entry[key], bool):
                raise FileFormatError(
                    p, f"{where}: '{key}' must be a frame name (a string or an integer)"
                )
        if "sigma" in entry and "cov" in entry:
            raise FileFormatError(p, f"{where}: give 'sigma' or 'cov', not both")
        try:
            at = _at(entry, scale, scale3)
        except (RelmapError, TypeError, ValueError) as exc:
            raise FileFormatError(p, f"{where}: {exc}") from None
        if records and type(at) is not type(records[0].at):
            raise FileFormatError(
                p, f"{where}: a {at.group} AT in a file of {records[0].at.group} ATs"
            )
        records.append(ATRecord(name, entry["from"], entry["to"], at))
    return records


def _at(entry: dict[str, Any], scale: np.ndarray, scale3: np.ndarray) -> AT | AT3:
    """The AT (3 mean numbers) or AT3 (7) of one entry, angles converted to radians."""
    raw = entry["mean"]
    if isinstance(raw, list) and len(raw) == 7:
        mean = _numbers(raw, (7,), "mean")
        if "sigma" in entry:
            sig = _numbers(entry["sigma"], (6,), "sigma") * scale3
            return AT3.from_sigmas(mean[:3], mean[3:], sig)
        cov = None
        if "cov" in entry:
            cov = _numbers(entry["cov"], (6, 6), "cov") * np.outer(scale3, scale3)
        return AT3.from_vector(mean, cov)
    mean = _numbers(raw, (3,), "mean") * scale
    if "sigma" in entry:
        return AT.from_sigmas(mean, _numbers(entry["sigma"], (3,), "sigma") * scale)
    if "cov" in entry:
        return AT(mean, _numbers(entry["cov"], (3, 3), "cov") * np.outer(scale, scale))
    return AT(mean)


def _numbers(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    if isinstance(value, (str, bytes)) or value is None:
        raise ValueError(f"{what} must be numbers; got {value!r}")
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{what} must have shape {shape}; got {arr.shape}")
    return arr


def write_records(
    path: str | os.PathLike[str], records: Iterable[ATRecord], *, description: str | None = None
) -> None:
    """Write records as a map file (JSON for ``.json``, YAML otherwise), atomically.

    Means and covariances are written in radians with full precision, so reading the file back
    gives the same numbers exactly.
    """
    p = Path(path)
    records = list(records)
    for r in records:
        if r.at.ndim:
            raise ValueError(
                f"AT {r.name!r} has batch shape {r.at.batch_shape}; map files hold single ATs"
            )
    doc: dict[str, Any] = {"relmap": FORMAT_VERSION}
    if description:
        doc["description"] = description
    doc["angle_unit"] = "rad"
    doc["ats"] = [
        {
            "name": r.name,
            "from": r.src,
            "to": r.dst,
            "mean": [float(v) for v in (r.at.vector if isinstance(r.at, AT3) else r.at.mean)],
            "cov": [[float(v) for v in row] for row in r.at.cov],
        }
        for r in records
    ]
    if p.suffix.lower() == ".json":
        text = json.dumps(doc, indent=2) + "\n"
    else:
        import yaml

        text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    write_text_atomic(p, text)
