"""Field checking for scenario files: a reader over one TOML table that names what is wrong.

Every error is a ScenarioError whose message is one line: ``<file>: <field path>: <what>``,
e.g. ``scenarios/x.toml: faults[2].drone: 12 is not a drone index (0..8)``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any


class ScenarioError(ValueError):
    """A mistake in a scenario file; the message names the file, the field and the problem."""


class _Missing:
    """Marker for "no default: the field is required"."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Missing()


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _type_name(x: object) -> str:
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    names.update({list: "an array", dict: "a table"})
    return names.get(type(x), type(x).__name__)


class Table:
    """Typed access to one TOML table at ``path`` of file ``source``.

    ``allowed``: the keys this table may have; any other key is an error naming it (with a
    suggestion for a likely typo) and listing the allowed ones.
    """

    def __init__(
        self, data: object, source: str, path: str, allowed: Iterable[str] | None = None
    ) -> None:
        self.source = source
        self.path = path
        if not isinstance(data, dict):
            raise self.error(f"must be a table, got {_type_name(data)}", here=True)
        self.data: dict[str, Any] = data
        if allowed is not None:
            self.allow(allowed)

    def where(self, key: str) -> str:
        """The field path of ``key`` in this table."""
        return f"{self.path}.{key}" if self.path else key

    def error(self, message: str, key: str | None = None, here: bool = False) -> ScenarioError:
        """A ScenarioError about ``key`` (or the table itself)."""
        field = self.path if here or key is None else self.where(key)
        return ScenarioError(f"{self.source}: {field or '(top level)'}: {message}")

    def allow(self, allowed: Iterable[str]) -> None:
        """Raise for the first key of this table not in ``allowed``."""
        names = sorted(allowed)
        for key in self.data:
            if key not in names:
                close = difflib.get_close_matches(key, names, n=1)
                hint = f"did you mean '{close[0]}'? " if close else ""
                raise self.error(f"unknown key ({hint}allowed: {', '.join(names)})", key)

    def has(self, key: str) -> bool:
        """Whether the table sets ``key``."""
        return key in self.data

    def raw(self, key: str, default: Any = REQUIRED) -> Any:
        """The value of ``key``, or ``default``; missing and required is an error."""
        if key in self.data:
            return self.data[key]
        if default is REQUIRED:
            raise self.error("missing (required)", key)
        return default

    def number(
        self,
        key: str,
        default: Any = REQUIRED,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> float:
        """A finite float (TOML integers accepted) within the given bounds."""
        if key not in self.data and default is not REQUIRED:
            return default
        return check_number(self.raw(key), self.source, self.where(key), gt, ge, lt, le)

    def optional_number(self, key: str, **bounds: float) -> float | None:
        """Like :meth:`number`, None when absent."""
        return self.number(key, **bounds) if key in self.data else None

    def integer(
        self, key: str, default: Any = REQUIRED, *, ge: int | None = None, le: int | None = None
    ) -> int:
        """An integer (not a boolean) within the given bounds."""
        if key not in self.data and default is not REQUIRED:
            return default
        return check_integer(self.raw(key), self.source, self.where(key), ge, le)

    def boolean(self, key: str, default: Any = REQUIRED) -> bool:
        """A boolean."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(f"must be true or false, got {_type_name(value)} {value!r}", key)
        return value

    def string(self, key: str, default: Any = REQUIRED) -> str:
        """A string."""
        value = self.raw(key, default)
        if not isinstance(value, str):
            raise self.error(f"must be a string, got {_type_name(value)} {value!r}", key)
        return value

    def numbers(
        self,
        key: str,
        n: int,
        default: Any = REQUIRED,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> tuple[float, ...]:
        """An array of exactly ``n`` finite numbers, each within the given bounds."""
        if key not in self.data and default is not REQUIRED:
            return tuple(default)
        items = self.array(key, n)
        return tuple(
            check_number(x, self.source, f"{self.where(key)}[{k}]", gt, ge, lt, le)
            for k, x in enumerate(items)
        )

    def vec3(
        self, key: str, default: Any = REQUIRED, **bounds: float
    ) -> tuple[float, float, float]:
        """An array of exactly 3 finite numbers (see :meth:`numbers`)."""
        x, y, z = self.numbers(key, 3, default, **bounds)
        return x, y, z

    def array(self, key: str, n: int | None = None) -> list[Any]:
        """An array (of exactly ``n`` items when given)."""
        value = self.raw(key)
        if not isinstance(value, list):
            raise self.error(f"must be an array, got {_type_name(value)} {value!r}", key)
        if n is not None and len(value) != n:
            raise self.error(f"must have {n} items, got {len(value)}", key)
        return value

    def table(self, key: str, allowed: Iterable[str] | None = None) -> Table:
        """The sub-table ``key`` (an empty one when absent)."""
        return Table(self.data.get(key, {}), self.source, self.where(key), allowed)

    def tables(self, key: str, allowed: Iterable[str] | None = None) -> list[Table]:
        """The array of tables ``key`` (``[[key]]``); empty when absent."""
        value = self.data.get(key, [])
        if not isinstance(value, list):
            raise self.error(
                f"must be an array of tables ([[{key}]]), got {_type_name(value)}", key
            )
        return [
            Table(item, self.source, f"{self.where(key)}[{k}]", allowed)
            for k, item in enumerate(value)
        ]

    def section(
        self, cls: Any, bounds: Mapping[str, Mapping[str, Any]] | None = None, **given: Any
    ) -> Any:
        """An instance of the dataclass ``cls`` (all fields defaulted) read from this table.

        Only ``cls``'s fields are allowed. Each field is typed like its default (bool, int, float
        or a fixed-length tuple of numbers) and checked against ``bounds[name]`` (gt/ge/lt/le);
        fields in ``given`` are taken as they are.
        """
        names = [f.name for f in dataclasses.fields(cls)]
        self.allow(names)
        defaults, bounds = cls(), bounds or {}
        values = dict(given)
        for name in names:
            if name in values:
                continue
            default, b = getattr(defaults, name), bounds.get(name, {})
            if isinstance(default, bool):
                values[name] = self.boolean(name, default)
            elif isinstance(default, int):
                values[name] = self.integer(name, default, **b)
            elif isinstance(default, tuple):
                values[name] = self.numbers(name, len(default), default, **b)
            else:
                values[name] = self.number(name, default, **b)
        return cls(**values)

    def index(self, key: str, n: int) -> int:
        """A drone index in ``0..n-1``."""
        return check_index(self.raw(key), self.source, self.where(key), n)

    def pair(self, key: str, n: int) -> tuple[int, int]:
        """Two different drone indices ``[i, j]``."""
        i, j = (
            check_index(x, self.source, f"{self.where(key)}[{k}]", n)
            for k, x in enumerate(self.array(key, 2))
        )
        if i == j:
            raise self.error(f"a link needs two different drones, got [{i}, {j}]", key)
        return i, j

    def groups(self, key: str, n: int) -> tuple[tuple[int, ...], ...]:
        """At least one non-empty array of drone indices, no drone in two of them."""
        groups: list[tuple[int, ...]] = []
        seen: dict[int, int] = {}
        for g, raw in enumerate(self.array(key)):
            where = f"{self.where(key)}[{g}]"
            if not isinstance(raw, list) or not raw:
                raise ScenarioError(f"{self.source}: {where}: must be a non-empty array of indices")
            members = tuple(
                check_index(x, self.source, f"{where}[{k}]", n) for k, x in enumerate(raw)
            )
            for k, i in enumerate(members):
                if i in seen:
                    raise ScenarioError(
                        f"{self.source}: {where}[{k}]: drone {i} is already in {key}[{seen[i]}]"
                    )
                seen[i] = g
            groups.append(members)
        if not groups:
            raise self.error("needs at least one group", key)
        return tuple(groups)


def check_index(value: object, source: str, field: str, n: int) -> int:
    """``value`` as a drone index in ``0..n-1``, else a ScenarioError about ``field``."""
    i = check_integer(value, source, field)
    if not 0 <= i < n:
        raise ScenarioError(f"{source}: {field}: {i} is not a drone index (0..{n - 1})")
    return i


def check_number(
    value: object,
    source: str,
    field: str,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
) -> float:
    """``value`` as a finite float within the bounds, else a ScenarioError about ``field``."""
    if not _is_number(value):
        raise ScenarioError(
            f"{source}: {field}: must be a number, got {_type_name(value)} {value!r}"
        )
    x = float(value)  # type: ignore[arg-type]
    if not math.isfinite(x):
        raise ScenarioError(f"{source}: {field}: must be a finite number, got {x}")
    violated = (
        (gt is not None and not x > gt, ">", gt),
        (ge is not None and not x >= ge, ">=", ge),
        (lt is not None and not x < lt, "<", lt),
        (le is not None and not x <= le, "<=", le),
    )
    for bad, op, bound in violated:
        if bad:
            raise ScenarioError(f"{source}: {field}: must be {op} {bound:g}, got {value!r}")
    return x


def check_integer(
    value: object, source: str, field: str, ge: int | None = None, le: int | None = None
) -> int:
    """``value`` as an int within ``[ge, le]``, else a ScenarioError about ``field``."""
    if not isinstance(value, int) or isinstance(value, bool):
        raise ScenarioError(
            f"{source}: {field}: must be an integer, got {_type_name(value)} {value!r}"
        )
    if ge is not None and value < ge:
        raise ScenarioError(f"{source}: {field}: must be >= {ge}, got {value}")
    if le is not None and value > le:
        raise ScenarioError(f"{source}: {field}: must be <= {le}, got {value}")
    return value
