"""YAML and XML calibration files as trees of dicts, lists, numbers, strings and arrays
(OpenCV FileStorage's ``%YAML:1.0`` header and ``!!opencv-matrix`` tags included)."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from ._common import _check_array, _check_image_size, _fail, _read_text, _shown, _to_float

#: The message for a file nested deeper than Python's recursion limit (no calibration is).
_TOO_DEEP = "nested too deeply to be a calibration file"


def _yaml() -> Any:
    try:
        import yaml
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            'reading YAML calibration files needs PyYAML: pip install "stereodepth[calib]"'
        ) from exc
    return yaml


def _opencv_matrix(node: Any, where: str, key: str) -> np.ndarray:
    """An ``opencv-matrix`` (rows, cols, dt, data) as a float64 (rows, cols[, channels]), or
    an ``opencv-nd-matrix`` (sizes, dt, data) as a float64 array of shape sizes[+ channels]."""
    if not isinstance(node, dict):
        raise _fail(where, f"{key}: an opencv-matrix must be a mapping, got {_shown(node)}")
    dims = ("sizes",) if "sizes" in node else ("rows", "cols")
    missing = [k for k in (*dims, "dt", "data") if k not in node]
    if missing:
        raise _fail(where, f"{key}: opencv-matrix without {', '.join(missing)}")
    sizes = node["sizes"] if dims == ("sizes",) else [node["rows"], node["cols"]]
    sizes = sizes if isinstance(sizes, list) else [sizes]
    shape: list[int] = []
    for name, v in zip(dims * len(sizes) if dims == ("sizes",) else dims, sizes, strict=True):
        f = _to_float(v)
        if f is None or not (f.is_integer() and f >= 0):
            raise _fail(
                where, f"{key}: opencv-matrix {name} must be whole numbers >= 0, got {_shown(v)}"
            )
        shape.append(int(f))
    dt = node["dt"]
    m = re.fullmatch(r"(\d*)([ucwsifdh])", str(dt).strip('"'))
    if m is None:
        raise _fail(
            where, f"{key}: opencv-matrix dt must be a type such as 'd' or 'f', got {_shown(dt)}"
        )
    channels = int(m.group(1) or 1)
    if channels != 1:
        shape.append(channels)
    data = node["data"]
    if isinstance(data, str | int | float):
        data = [data]
    if not isinstance(data, list):
        raise _fail(
            where, f"{key}: opencv-matrix data must be a list of numbers, got {_shown(data)}"
        )
    values = [_to_float(v) for v in data]
    bad = [v for v, f in zip(data, values, strict=True) if f is None]
    if bad:
        raise _fail(where, f"{key}: opencv-matrix data must be numbers, got {_shown(bad[0])}")
    count = math.prod(shape)
    if len(values) != count:
        raise _fail(
            where,
            f"{key}: opencv-matrix of {'x'.join(map(str, shape))} needs {count} values, "
            f"got {len(values)}",
        )
    return np.array(values, dtype=np.float64).reshape(shape)


#: FileStorage's matrix types (``!!opencv-matrix`` in YAML, ``type_id`` in XML and JSON).
_MATRIX_TYPES = ("opencv-matrix", "opencv-nd-matrix")


def _yaml_tree(p: Path, text: str) -> dict[str, Any]:
    """A YAML file as a dict, also OpenCV's: the ``%YAML:1.0`` directive (which YAML parsers
    reject) dropped, ``!!opencv-matrix`` nodes as arrays; FileStorage's JSON too (a YAML
    subset: its matrices are mappings with ``"type_id": "opencv-matrix"``). Duplicate keys are
    refused."""
    yaml = _yaml()
    where = str(p)

    class Loader(yaml.SafeLoader):  # type: ignore[misc, name-defined]
        pass

    class RawMatrix(dict):  # type: ignore[type-arg]
        """An ``!!opencv-matrix`` node, converted once its key is known."""

    def mapping(loader: Any, node: Any) -> dict[Any, Any]:
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=True)
            if not isinstance(key, str | int | float):
                raise _fail(where, f"keys must be names, got {_shown(key)}")
            if key in out:
                raise _fail(where, f"{key} is given twice (line {key_node.start_mark.line + 1})")
            value = loader.construct_object(value_node, deep=True)
            if type(value) is RawMatrix:
                value = _opencv_matrix(value, where, str(key))
            elif type(value) is dict and value.get("type_id") in _MATRIX_TYPES:
                # FileStorage's JSON (a YAML subset): the tag is a "type_id" key
                value = _opencv_matrix(
                    {k: v for k, v in value.items() if k != "type_id"}, where, str(key)
                )
            out[key] = value
        return out

    def matrix(loader: Any, node: Any) -> RawMatrix:
        if not isinstance(node, yaml.MappingNode):
            # mapping() took its items for key-value pairs: Python's "cannot unpack
            # non-iterable ScalarNode object" (a TypeError) named neither file nor line.
            got = "a sequence" if isinstance(node, yaml.SequenceNode) else _shown(node.value)
            raise _fail(
                where,
                f"line {node.start_mark.line + 1}: an {node.tag.rsplit(':', 1)[-1]} must be a "
                f"mapping (rows and cols, or sizes; dt, data), got {got}",
            )
        return RawMatrix(mapping(loader, node))

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
    Loader.add_constructor("tag:yaml.org,2002:opencv-nd-matrix", matrix)
    # OpenCV writes "%YAML:1.0" (before 5.0; "%YAML 1.2" since): a YAML 1.1 parser wants
    # neither. Blank the line, keeping the line numbers of error messages.
    text = re.sub(r"\A%YAML[: ]?[ \t]*\d+\.\d+[ \t]*", "", text)
    # `rostopic echo` and `ros2 topic echo` end each message with a "---" line: one message
    # saved to a file is one document followed by an empty one.
    text = re.sub(r"\n---[ \t]*\n?\s*\Z", "\n", text)
    try:
        tree = yaml.load(text, Loader=Loader)  # a SafeLoader: no arbitrary objects
    except yaml.YAMLError as exc:
        raise _fail(where, f"not valid YAML: {' '.join(str(exc).split())}") from exc
    except RecursionError:
        raise _fail(where, _TOO_DEEP) from None
    if not isinstance(tree, dict):
        raise _fail(where, f"a calibration file must be a YAML mapping, got {type(tree).__name__}")
    return tree


def _xml_value(el: ET.Element, where: str) -> Any:
    key = el.tag
    if el.get("type_id") in _MATRIX_TYPES:
        node = {c.tag: (c.text or "").split() for c in el}
        flat: dict[str, Any] = {
            k: (v[0] if k != "data" and len(v) == 1 else v) for k, v in node.items()
        }
        return _opencv_matrix(flat, where, key)
    children = list(el)
    if children:
        if all(c.tag == "_" for c in children):
            return [_xml_value(c, where) for c in children]
        out: dict[str, Any] = {}
        for c in children:
            if c.tag in out:
                raise _fail(where, f"{c.tag} is given twice")
            out[c.tag] = _xml_value(c, where)
        return out
    words = (el.text or "").split()
    numbers = [_to_float(w) for w in words]
    if words and all(n is not None for n in numbers):
        vals = [
            int(n) if n is not None and n.is_integer() and "." not in w else n
            for n, w in zip(numbers, words, strict=True)
        ]
        return vals[0] if len(vals) == 1 else vals
    return " ".join(words).strip('"')


def _xml_tree(p: Path, text: str) -> dict[str, Any]:
    """An OpenCV FileStorage XML file (``<opencv_storage>``) as a dict, matrices as arrays."""
    where = str(p)
    if re.search(r"<!(DOCTYPE|ENTITY)", text):
        raise _fail(where, "XML with a DOCTYPE or entities is not an OpenCV FileStorage file")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise _fail(where, f"not valid XML: {exc}") from exc
    if root.tag != "opencv_storage":
        raise _fail(where, f"the XML root must be <opencv_storage>, got <{root.tag}>")
    try:
        tree = _xml_value(root, where)
    except RecursionError:
        raise _fail(where, _TOO_DEEP) from None
    return tree if isinstance(tree, dict) else {}


def _lookup(tree: dict[str, Any], names: tuple[str, ...], where: str) -> tuple[str, Any] | None:
    """The one key of ``names`` present in ``tree`` (None if none; ValueError if several)."""
    found = [n for n in names if n in tree]
    if len(found) > 1:
        raise _fail(where, f"both {found[0]} and {found[1]} are given: which one holds the matrix?")
    return (found[0], tree[found[0]]) if found else None


def _require(tree: dict[str, Any], names: tuple[str, ...], where: str) -> tuple[str, Any]:
    hit = _lookup(tree, names, where)
    if hit is None:
        raise _fail(where, f"missing key {' or '.join(names)}")
    return hit


def _unset_size(value: Any) -> bool:
    """A size written as 0 x 0: how ROS camera_info (and camera_info_manager's defaults) say
    the size is not known."""
    try:
        w, h = value.reshape(-1).tolist() if isinstance(value, np.ndarray) else value
    except (TypeError, ValueError):
        return False
    return not isinstance(w, bool) and not isinstance(h, bool) and w == 0 and h == 0


def _file_image_size(tree: dict[str, Any], where: str) -> tuple[int, int] | None:
    """The image size under the names calibration tools use, if any; None when absent or
    written as 0 x 0 (not known: the caller's image_size then gives it)."""
    hit = _lookup(tree, ("image_size", "imageSize", "img_size", "resolution"), where)
    if hit is not None:
        key, value = hit
        return None if _unset_size(value) else _check_image_size(value, where, key)
    for wk, hk in (
        ("image_width", "image_height"),
        ("imageWidth", "imageHeight"),
        ("width", "height"),
    ):
        if wk in tree or hk in tree:
            if wk not in tree or hk not in tree:
                raise _fail(
                    where, f"{wk} and {hk} go together, got only {wk if wk in tree else hk}"
                )
            if _unset_size((tree[wk], tree[hk])):
                return None
            return _check_image_size((tree[wk], tree[hk]), where, f"{wk}, {hk}")
    return None


def _read_tree(p: Path, what: str) -> tuple[str, dict[str, Any]]:
    text = _read_text(p, what)
    head = text.lstrip()
    if head.startswith(("<?xml", "<opencv_storage")):
        return "xml", _xml_tree(p, text)
    return "yaml", _yaml_tree(p, text)


def _ros_matrix(tree: dict[str, Any], key: str, where: str, shape: tuple[int, ...]) -> np.ndarray:
    """A ROS camera_info matrix: ``{rows, cols, data}``."""
    if key not in tree:
        raise _fail(where, f"missing key {key}")
    node = tree[key]
    if isinstance(node, dict) and "data" in node:
        data = node["data"]
        rows, cols = node.get("rows"), node.get("cols")
        if not isinstance(data, list):
            raise _fail(where, f"{key}.data must be a list of numbers, got {_shown(data)}")
        values = [_to_float(v) for v in data]
        if any(v is None for v in values):
            raise _fail(where, f"{key}.data must be numbers, got {_shown(data)}")
        r, c = _to_float(rows), _to_float(cols)
        if r is None or c is None or not (r.is_integer() and c.is_integer()) or r < 0 or c < 0:
            raise _fail(
                where,
                f"{key} rows and cols must be whole numbers, got {_shown(rows)}, {_shown(cols)}",
            )
        if len(values) != r * c:
            raise _fail(
                where, f"{key} of {int(r)}x{int(c)} needs {int(r * c)} values, got {len(values)}"
            )
        a = np.array(values, dtype=np.float64).reshape(int(r), int(c))
    elif isinstance(node, np.ndarray):
        a = node
    else:
        raise _fail(where, f"{key} must be a mapping with rows, cols and data, got {_shown(node)}")
    return _check_array(a, where, key, shape)


def _numbers(value: Any, where: str, key: str) -> list[float]:
    if not isinstance(value, list):
        raise _fail(where, f"{key} must be a list of numbers, got {_shown(value)}")
    out = [_to_float(v) for v in value]
    if any(v is None for v in out):
        raise _fail(where, f"{key} must be a list of numbers, got {_shown(value)}")
    return [float(v) for v in out if v is not None]
