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
import re
import sys
from collections.abc import Hashable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from relmap.errors import FileFormatError, ParameterError, RelmapError, ShapeError
from relmap.io import formats
from relmap.io.atomic import check_writable, write_text_atomic
from relmap.io.textfile import Input
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3

__all__ = ["ATRecord", "read_records", "records_from_text", "write_records"]

FORMAT_VERSION = 1
_ENTRY_KEYS = {"name", "from", "to", "mean", "sigma", "cov"}
_TOP_KEYS = {"relmap", "description", "angle_unit", "ats"}


class ATRecord(NamedTuple):
    """One AT of a map file: ``at`` says where frame ``dst`` is, seen from frame ``src``."""

    name: str
    src: Hashable
    dst: Hashable
    at: AT | AT3


def _is_json(path: Path) -> bool:
    """JSON for a ``.json`` (or ``.json.gz``) name, YAML for any other."""
    name = path.name.lower().removesuffix(".gz")
    return name.endswith(".json")


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


class _DuplicateKey(ValueError):
    pass


def _line_of(text: str, index: int) -> int:
    """1-based line of character ``index``: lines end at LF only (as grep -n counts them)."""
    return text.count("\n", 0, max(index, 0)) + 1


def _too_long(exc: ValueError) -> str:
    if "digits" in str(exc):
        return f"an integer of more than {sys.get_int_max_str_digits()} digits"
    return str(exc)


def _parse_json(path: Path, text: str) -> Any:
    try:
        return json.loads(text, object_pairs_hook=_unique_pairs)
    except json.JSONDecodeError as exc:
        raise FileFormatError(path, f"invalid JSON: {exc.msg}", line=exc.lineno) from None
    except _DuplicateKey as exc:
        raise FileFormatError(path, f"invalid JSON: duplicate key {exc.args[0]!r}") from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise FileFormatError(path, f"invalid JSON: {_too_long(exc)}") from None
    except RecursionError:
        raise FileFormatError(path, "invalid JSON: nested too deeply") from None


def _yaml_loader():  # type: ignore[no-untyped-def]
    """yaml's safe loader refusing duplicate keys (it would keep the last one silently): libyaml's
    C parser where PyYAML has it (``CSafeLoader``; the pure-Python scanner is quadratic on some
    inputs), the same safe constructor either way."""
    import yaml  # lazy: only map files need it

    class Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
        def construct_mapping(self, node, deep=False):  # type: ignore[no-untyped-def]
            seen: set[object] = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    repeated = key in seen
                    seen.add(key)
                except TypeError:  # an unhashable key: yaml reports it below
                    continue
                if repeated:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key!r}", key_node.start_mark
                    )
            return super().construct_mapping(node, deep=deep)

    return Loader


def _parse_yaml(path: Path, text: str) -> Any:
    import yaml

    try:
        return yaml.load(text, Loader=_yaml_loader())  # a SafeLoader subclass: safe
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = _line_of(text, mark.index) if mark is not None else None
        problem = str(getattr(exc, "problem", None) or exc)
        if "nesting depth" in problem:  # libyaml's limit (1000 levels), said as for JSON
            problem = "nested too deeply"
        raise FileFormatError(path, f"invalid YAML: {problem}", line=line) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise FileFormatError(path, f"invalid YAML: {_too_long(exc)}") from None
    except RecursionError:
        raise FileFormatError(path, "invalid YAML: nested too deeply") from None


def _parse(path: Path, text: str) -> Any:
    return _parse_json(path, text) if _is_json(path) else _parse_yaml(path, text)


def read_records(path: str | os.PathLike[str] | Input) -> list[ATRecord]:
    """Read a map file (``.json``, or YAML for any other suffix; gzip, a BOM, CRLF and pipes
    accepted: :func:`relmap.io.textfile.read_input`) into :class:`ATRecord` s; a file in another
    format is refused naming it (:func:`relmap.io.formats.read`)."""
    records: list[ATRecord] = formats.read(path, (formats.Kind.MAP,))[1]
    return records


def records_from_text(p: Path, text: str) -> list[ATRecord]:
    """:func:`read_records` of text already read from the file ``p`` (named in errors)."""
    doc = _parse(p, text)
    if not isinstance(doc, dict):
        raise FileFormatError(p, "expected a mapping with an 'ats' list at the top level")
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise FileFormatError(p, f"unknown top-level key(s) {sorted(map(str, unknown))}")
    version = doc.get("relmap", FORMAT_VERSION)
    if type(version) is not int or version != FORMAT_VERSION:  # True == 1, 1.0 == 1
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
        name = entry.get("name", f"e{i}")
        if not isinstance(name, (str, int)) or isinstance(name, bool):
            raise FileFormatError(p, f"{where}: 'name' must be a string or an integer")
        name = str(name)
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


#: Decimal numbers that YAML 1.1 leaves as text (an exponent without a dot: ``9e-4``, ``1E3``).
_YAML11_FLOAT = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+")


def _numbers(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``value`` (nested lists of int/float, never bool or text) as a float array of ``shape``."""
    flat: list[float] = []
    stack = [(value, 0)]
    while stack:  # no recursion: depth is bounded by the shape
        item, depth = stack.pop()
        if isinstance(item, list) and depth < len(shape):
            stack.extend((v, depth + 1) for v in reversed(item))
        elif isinstance(item, str) and depth == len(shape) and _YAML11_FLOAT.fullmatch(item):
            flat.append(float(item))  # YAML 1.1 (PyYAML) reads 9e-4, 1e3 as text
        elif isinstance(item, (int, float)) and not isinstance(item, bool) and depth == len(shape):
            try:
                flat.append(float(item))
            except OverflowError:
                raise ValueError(f"{what} holds a number too large for a float") from None
        else:
            raise ValueError(f"{what} must hold numbers (shape {shape}); got {_brief(item)}")
    try:
        arr = np.array(value, dtype=np.float64)
    except (ValueError, OverflowError):
        raise ValueError(f"{what} must have shape {shape}; its rows differ in length") from None
    if arr.shape != shape:
        raise ValueError(f"{what} must have shape {shape}; got {arr.shape}")
    return arr


def _brief(item: Any) -> str:
    text = repr(item)
    return f"{type(item).__name__} {text if len(text) <= 40 else text[:40] + '…'}"


def _frame_for_file(frame: object, name: str, key: str) -> str | int:
    """A frame as map files hold it (a string or an integer), or a clear error at save."""
    if isinstance(frame, np.integer):
        return int(frame)
    if isinstance(frame, (str, int)) and not isinstance(frame, bool):
        return frame
    raise ParameterError(
        f"AT {name!r}: its '{key}' frame {frame!r} is a {type(frame).__name__}; map files "
        "hold frames named by strings or integers (rename the frames before saving)"
    )


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
            raise ShapeError(
                f"AT {r.name!r} has batch shape {r.at.batch_shape}; map files hold single ATs"
            )
        if not isinstance(r.name, str):
            raise ParameterError(f"AT name {r.name!r} must be a string")
    check_writable(p)
    doc: dict[str, Any] = {"relmap": FORMAT_VERSION}
    if description:
        doc["description"] = description
    doc["angle_unit"] = "rad"
    doc["ats"] = [
        {
            "name": r.name,
            "from": _frame_for_file(r.src, r.name, "from"),
            "to": _frame_for_file(r.dst, r.name, "to"),
            "mean": [float(v) for v in r.at.vector],
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


# ----------------------------------------------------------------------------------- the format
def _is_map(head: formats.Head) -> bool:
    """A map file: its first record opens a YAML/JSON mapping or sequence (``{``, ``[``), a
    YAML document (``---``, ``%``) or a quoted key, or is a key (``ats:``, ``relmap: 1``)."""
    record = head.record
    return bool(record) and (
        record.startswith(("{", "[", "---", "%", '"', "'")) or record.split(None, 1)[0][-1] == ":"
    )


def _read(source: Input) -> list[ATRecord]:
    assert source.text is not None  # recognised from a text record
    return records_from_text(source.path, source.text)


formats.register(
    formats.Format(
        "map",
        formats.Kind.MAP,
        "relmap's map file: YAML, or JSON for a .json name, with a list 'ats'",
        _is_map,
        _read,
        write_records,
    )
)
