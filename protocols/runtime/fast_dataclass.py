"""Making instances of frozen dataclasses cheaply: :func:`frozen_factory`.

Why ``exec``: the maker is generated once per class, as :mod:`dataclasses` generates the
``__init__`` itself, so that it stores each field directly (one statement per field). The plain
alternatives were measured (a 12-field :class:`~protocols.wire.consensus_message.ConsensusMessage`,
CPython 3.11): the generated maker 390-420 ns, ``o.__dict__.update(zip(names, values))`` 720 ns,
``object.__setattr__(o, "__dict__", dict(zip(...)))`` 1000 ns, the frozen ``__init__`` ~4 times
the generated one; an agent makes about eight such objects a tick, so a plain maker would add
~20 us to a 9-agent tick of ~220 us (~10 %).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields
from typing import Any, TypeVar

_T = TypeVar("_T")
_FACTORIES: dict[type, Callable[..., Any]] = {}


def frozen_factory(cls: type[_T]) -> Callable[..., _T]:
    """A maker of instances of the frozen dataclass ``cls`` (no ``__post_init__``, no init-only
    fields, no slots) from all its fields, positionally in declaration order: the same object as
    ``cls(...)``, its ``__dict__`` filled directly instead of through the frozen ``__init__``'s
    ``object.__setattr__`` per field (about 4 times cheaper: a hundred agents make thousands of
    output and message fields a tick). Generated once per class, as dataclasses makes its
    ``__init__``."""
    maker = _FACTORIES.get(cls)
    if maker is None:
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        body = "".join(f"    d[{name!r}] = {name}\n" for name in names)
        head = f"def make({', '.join(names)}):\n    o = new(cls)\n    d = o.__dict__\n"
        source = f"{head}{body}    return o\n"
        scope: dict[str, Any] = {"new": object.__new__, "cls": cls}
        exec(source, scope)  # field names of a dataclass are identifiers
        maker = _FACTORIES[cls] = scope["make"]
    return maker
