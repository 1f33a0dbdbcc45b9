"""Reading and checking the project's TOML files: one error type, one way to declare keys.

The service (``configs/service.toml``) and the simulator (``sitl.toml``, scenarios, the
vehicle file) share this module and nothing else: it imports neither, so MAVLink stays
their only contract. A setting is declared where it is read, with its type, its default
(taken from the dataclass it fills, never repeated as a literal) and a check that returns
the reason a value is refused::

    r = TableReader(file, doc)
    imu = r.sub("imu")
    rate_hz = imu.get("rate_hz", float, defaults.rate_hz, within(0.0, 1e4, lo_open=True))
    imu.done()  # any other key of [imu] is an error: a typo must not fall back to a default

Every refusal is a :class:`ConfigError` naming the file, the dotted key and the reason
(``sitl.toml: imu.rate_hz: must be in (0, 10000], got -1.0``); the commands print it and
exit 2.

A file is read by :func:`read_limited` before it is parsed: a regular file (a FIFO, a
device such as ``/dev/zero`` or a directory is refused, without blocking: opened with
``O_NONBLOCK`` and checked with ``fstat`` before a byte is read), at most
:data:`MAX_FILE_BYTES`; :func:`load_toml` then refuses a UTF-8 byte order mark, text
that is not UTF-8 and arrays or inline tables nested deeper than :data:`MAX_NESTING`,
each with its reason.
"""

from __future__ import annotations

import math
import os
import stat
import tomllib
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Final

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_NESTING",
    "REQUIRED",
    "Check",
    "ConfigError",
    "TableReader",
    "file_kind",
    "load_toml",
    "one_of",
    "read_limited",
    "within",
]


class ConfigError(ValueError):
    """A bad configuration file or value: ``file``, ``key`` (dotted; ``-`` for the whole
    file) and ``reason``; ``str()`` is ``"file: key: reason"``."""

    def __init__(self, file: str | Path, key: str, reason: str) -> None:
        super().__init__(f"{file}: {key}: {reason}")
        self.file = str(file)
        self.key = key
        self.reason = reason


#: A check: None if the value is acceptable, else the reason it is not.
Check = Callable[[Any], str | None]


def _num(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def within(lo: float, hi: float, *, lo_open: bool = False) -> Check:
    """A closed range [lo, hi] (or (lo, hi] with ``lo_open``): every number has one."""

    def check(x: Any) -> str | None:
        ok = (lo < x if lo_open else lo <= x) and x <= hi
        return None if ok else f"must be in {'(' if lo_open else '['}{_num(lo)}, {_num(hi)}]"

    return check


def one_of(*choices: str) -> Check:
    """One of the given strings."""

    def check(x: Any) -> str | None:
        return None if x in choices else f"must be one of {', '.join(choices)}"

    return check


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: The default of a key that must be given.
REQUIRED: Final[Any] = _Required()

_KIND_NAMES = {float: "a number", int: "an integer", bool: "true or false", str: "a string"}


#: The largest configuration file read (the project's largest is ~10 kB).
MAX_FILE_BYTES: Final = 1_000_000
#: The deepest nesting of arrays and tables accepted (the project's files use 3).
MAX_NESTING: Final = 32
_BOM = b"\xef\xbb\xbf"


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, for a message ("a FIFO", "a device"...)."""
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def read_limited(path: str | Path, max_bytes: int = MAX_FILE_BYTES, *, key: str = "-") -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes``; a
    :class:`ConfigError` (about ``key``) for anything else, never a wait or an
    unbounded read."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise ConfigError(p, key, "file not found") from None
    except OSError as err:
        raise ConfigError(p, key, f"cannot read: {err.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(p, key, f"is {file_kind(st.st_mode)}, not a regular file: refused")
        if st.st_size > max_bytes:
            raise ConfigError(p, key, f"{st.st_size:,} bytes: larger than {max_bytes:,}: refused")
        chunks = []
        n = 0
        while n <= max_bytes:  # the file may grow while read: never more than the limit
            chunk = os.read(fd, max_bytes + 1 - n)
            if not chunk:
                break
            chunks.append(chunk)
            n += len(chunk)
        if n > max_bytes:
            raise ConfigError(p, key, f"larger than {max_bytes:,} bytes: refused")
        return b"".join(chunks)
    except OSError as err:
        raise ConfigError(p, key, f"cannot read: {err.strerror}") from None
    finally:
        os.close(fd)


def _depth(value: Any) -> int:
    """How deeply ``value`` nests lists and tables (a scalar: 0), without recursion."""
    deepest = 0
    stack = [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            stack.extend((x, d + 1) for x in v.values())
        elif isinstance(v, list):
            stack.extend((x, d + 1) for x in v)
        else:
            deepest = max(deepest, d)
            continue
        deepest = max(deepest, d + 1)
        if deepest > MAX_NESTING + 1:
            break
    return deepest


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse ``path`` as TOML; a missing, unreadable, oversized, non-regular or malformed
    file is a ConfigError saying why."""
    p = Path(path)
    data = read_limited(p)
    if data.startswith(_BOM):
        raise ConfigError(
            p, "-", "starts with a UTF-8 byte order mark (BOM), which TOML does not allow: "
            "save it as UTF-8 without BOM"
        )  # fmt: skip
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(
            p, "-", f"not UTF-8 text (byte {err.start}: {err.object[err.start]:#04x})"
        ) from None
    deep = f"arrays or tables nested deeper than {MAX_NESTING} levels: refused"
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(p, "-", f"not valid TOML: {err}") from None
    except RecursionError:  # the parser recurses once per level: far too deep
        raise ConfigError(p, "-", deep) from None
    if _depth(doc) - 1 > MAX_NESTING:  # the document itself is not a level
        raise ConfigError(p, "-", deep)
    return doc


class TableReader:
    """Reads typed keys from one TOML table, remembering which were read (:meth:`done`)."""

    def __init__(self, file: str | Path, table: Mapping[str, Any], prefix: str = "") -> None:
        self.file = str(file)
        self.table = table
        self.prefix = prefix
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        """The dotted key of ``name`` in this table (for error messages)."""
        return f"{self.prefix}{name}"

    def error(self, name: str, reason: str) -> ConfigError:
        """A :class:`ConfigError` about key ``name`` of this table."""
        return ConfigError(self.file, self.key(name), reason)

    def has(self, name: str) -> bool:
        return name in self.table

    def _value(self, name: str, value: Any, kind: type, check: Check | None) -> Any:
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if (kind is int and isinstance(value, bool)) or not isinstance(value, kind):
            raise self.error(
                name, f"expected {_KIND_NAMES.get(kind, kind.__name__)}, got {value!r}"
            )
        if isinstance(value, float) and not math.isfinite(value):
            raise self.error(name, f"must be finite, got {value!r}")
        if check is not None:
            reason = check(value)
            if reason is not None:
                raise self.error(name, f"{reason}, got {value!r}")
        return value

    def get(
        self, name: str, kind: type, default: Any = REQUIRED, check: Check | None = None
    ) -> Any:
        """``table[name]`` as ``kind`` (an int is accepted as a float), finite, passing
        ``check``; ``default`` when absent (:data:`REQUIRED`: an error)."""
        self.used.add(name)
        if name not in self.table:
            if default is REQUIRED:
                raise self.error(name, "missing")
            return default
        return self._value(name, self.table[name], kind, check)

    def vector(
        self, name: str, n: int | None, default: Any = REQUIRED, check: Check | None = None
    ) -> tuple[float, ...]:
        """A list of ``n`` numbers (``None``: at least one), each finite and passing ``check``."""
        self.used.add(name)
        if name not in self.table:
            if default is REQUIRED:
                raise self.error(name, "missing")
            return tuple(default)
        v = self.table[name]
        count = f"{n}" if n is not None else "one or more"
        if not isinstance(v, list) or (len(v) != n if n is not None else not v):
            raise self.error(name, f"expected a list of {count} numbers, got {v!r}")
        return tuple(self._value(f"{name}[{i}]", e, float, check) for i, e in enumerate(v))

    def sub(self, name: str) -> TableReader:
        """The sub-table ``[name]`` (empty when absent)."""
        self.used.add(name)
        value = self.table.get(name, {})
        if not isinstance(value, Mapping):
            raise self.error(name, f"expected a table, got {value!r}")
        return TableReader(self.file, value, f"{self.prefix}{name}.")

    def tables(self, name: str) -> list[TableReader]:
        """The array of tables ``[[name]]`` (empty when absent)."""
        self.used.add(name)
        value = self.table.get(name, [])
        if not isinstance(value, list):
            raise self.error(name, f"expected an array of tables [[{self.key(name)}]]")
        out = []
        for i, t in enumerate(value):
            if not isinstance(t, Mapping):
                raise self.error(f"{name}[{i}]", "expected a table")
            out.append(TableReader(self.file, t, f"{self.prefix}{name}[{i}]."))
        return out

    def expect(self, names: Iterable[str]) -> None:
        """Declare this table's keys up front: any other key is an error now (not at
        :meth:`done`), before a misspelt required key is reported as missing."""
        known = set(names)
        for k in self.table:
            if k not in known:
                raise self.error(k, f"unknown key (known: {', '.join(sorted(known))})")

    def done(self) -> None:
        """Every key of the table must have been read: an unknown key is an error."""
        for k in self.table:
            if k not in self.used:
                known = ", ".join(sorted(self.used))
                raise self.error(k, f"unknown key (known: {known})" if known else "unknown key")
