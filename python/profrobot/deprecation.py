"""Old names kept working for one release, each with a DeprecationWarning naming the new one.

Vocabulary (the README's "The public API"): an iteration budget is ``iterations`` (or
``<phase>_iterations``), never ``iters``/``max_iters``/``steps``; ``steps`` counts waypoints or
samples of a path. Results say ``poses`` or ``path``, ``certified``, ``iterations`` and
``seconds``; a robot's identity is ``fingerprint``; joint ranges are ``joint_limits``.
"""

from __future__ import annotations

import functools
import inspect
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["renamed_arguments", "deprecated_alias"]

F = TypeVar("F", bound=Callable[..., Any])


def renamed_arguments(**old_to_new: str) -> Callable[[F], F]:
    """Accept each keyword argument ``old`` as ``old_to_new[old]`` with a DeprecationWarning;
    passing both names is a TypeError."""

    def wrap(fn: F) -> F:
        params = inspect.signature(fn).parameters
        for new in old_to_new.values():
            if new not in params:
                raise TypeError(f"{fn.__qualname__} has no parameter {new!r} to rename to")

        @functools.wraps(fn)
        def inner(*args, **kwargs):
            for old, new in old_to_new.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{fn.__name__}() got both {old!r} (deprecated) and {new!r}")
                    warnings.warn(f"{fn.__name__}({old}=...) is deprecated; use {new}=...", DeprecationWarning,
                                  stacklevel=2)
                    kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        inner.__deprecated_arguments__ = dict(old_to_new)  # type: ignore[attr-defined]
        return inner  # type: ignore[return-value]

    return wrap


class deprecated_alias:
    """A read-only attribute that returns ``obj.<new>`` with a DeprecationWarning (renamed result
    fields and attributes): ``free = deprecated_alias("certified")`` in a class body."""

    def __init__(self, new: str):
        self.new = new
        self.name = "?"
        self.__doc__ = f"Deprecated name of :attr:`{new}`."

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        warnings.warn(f"{type(obj).__name__}.{self.name} is deprecated; use .{self.new}", DeprecationWarning,
                      stacklevel=2)
        return getattr(obj, self.new)
