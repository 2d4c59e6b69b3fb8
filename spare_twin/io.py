"""Small file helpers: atomic writes (temporary name, then rename) and strict image reading."""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes 0600 files; give the final file the usual permissions.
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json_atomic(path: str | Path, obj) -> None:
    write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


#: Deepest nesting of arrays and objects accepted (the project's files nest at most about 6 deep);
#: Python's parser recurses per level and dies with RecursionError near 1,000.
MAX_JSON_DEPTH = 64
#: Most digits in a JSON integer (a 128-bit seed has 39); Python itself refuses past 4,300 with a ValueError.
MAX_JSON_INT_DIGITS = 100
#: Largest JSON file read whole, bytes: recordings and configurations are kilobytes to a few megabytes.
MAX_JSON_BYTES = 256 * 2**20

_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)


def json_depth(text: str) -> int:
    """Deepest nesting of [ and { in JSON `text` (brackets inside strings do not count)."""
    chars = np.frombuffer(_JSON_STRING.sub("", text).encode("utf-8", "replace"), np.uint8)
    steps = np.isin(chars, (ord("["), ord("{"))).astype(np.int64) - np.isin(chars, (ord("]"), ord("}")))
    return int(np.cumsum(steps).max(initial=0))


def _bounded_int(literal: str) -> int:
    digits = len(literal.lstrip("-"))
    if digits > MAX_JSON_INT_DIGITS:
        raise ValueError(f"an integer of {digits} digits, at most {MAX_JSON_INT_DIGITS}")
    return int(literal)


def parse_json(text: str, where: str):
    """JSON `text` parsed with its nesting and integer sizes bounded; a one-line error names `where`."""
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise SpareTwinError(f"{where}: not valid JSON (nested {depth} deep, at most {MAX_JSON_DEPTH})")
    try:
        return json.loads(text, parse_int=_bounded_int)
    except ValueError as exc:  # JSONDecodeError included
        raise SpareTwinError(f"{where}: not valid JSON ({exc})") from None
    except RecursionError:
        raise SpareTwinError(f"{where}: not valid JSON (nested too deep)") from None


def read_json(path: str | Path):
    """A user's JSON file, bounded (size, nesting, integer digits); every failure is one line naming it."""
    path = Path(path)
    try:
        if path.is_file() and path.stat().st_size > MAX_JSON_BYTES:
            raise SpareTwinError(f"{path}: {path.stat().st_size:,} bytes, too large for a JSON file of ours")
        text = path.read_text()
    except FileNotFoundError:
        raise SpareTwinError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise SpareTwinError(f"{path}: is a folder, not a JSON file") from None
    except OSError as exc:
        raise SpareTwinError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise SpareTwinError(f"{path}: not valid JSON ({exc})") from None
    return parse_json(text, str(path))


def read_npy(path: str | Path) -> np.ndarray:
    """A user's .npy file (no pickles), its header checked against the file's size before numpy allocates
    for it; a missing, truncated or garbled file is one line naming it."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0)):  # what np.save writes; 3.0 only adds unicode field names
                raise ValueError(f"format version {version[0]}.{version[1]}")
            read_header = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )
            shape, _, dtype = read_header(f)
            need = int(np.prod(shape, dtype=object)) * dtype.itemsize
            have = path.stat().st_size - f.tell()
            if dtype.hasobject:
                raise ValueError("it holds Python objects, which are not read")
            if need > have:
                raise ValueError(f"the header promises {need:,} bytes of {dtype} {shape}, the file holds {have:,}")
            f.seek(0)
            return np.load(f, allow_pickle=False)
    except FileNotFoundError:
        raise SpareTwinError(f"{path}: no such file") from None
    except Exception as exc:  # numpy's header parser raises ValueError, SyntaxError, tokenize errors...
        raise SpareTwinError(f"{path}: not a readable .npy file ({' '.join(str(exc).split())[:160]})") from None


@contextmanager
def atomic_dir(final: str | Path, overwrite: bool = True):
    """Yield a temporary sibling folder; on success it replaces `final` in one rename.

    On any error the temporary folder is removed and `final` is left exactly as it was.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    if final.exists() and not overwrite:
        raise SpareTwinError(f"{final}: already exists")
    if final.exists() and not final.is_dir():
        raise SpareTwinError(f"{final}: exists and is not a folder")
    tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".tmp"))
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if final.exists():
        old = final.parent / f".{final.name}.old-{os.getpid()}"
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def read_png(path: str | Path, flags: int | None = None) -> np.ndarray:
    """Read a PNG with OpenCV; a missing or corrupt file is a one-line SpareTwinError naming it."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise SpareTwinError(f"{path}: no such file")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED if flags is None else flags)
    if img is None:
        raise SpareTwinError(f"{path}: not a readable image (corrupt or truncated?)")
    return img


def encode_png(img: np.ndarray, compression: int = 1) -> bytes:
    """PNG bytes; deterministic for the same array (no timestamps in OpenCV's PNGs)."""
    import cv2

    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise SpareTwinError("could not encode a PNG image")
    return buf.tobytes()
