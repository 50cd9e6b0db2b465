"""The public surface is fully annotated: every parameter and return of every function named in
the ``__all__`` of every profrobot module, and of the public methods (and ``__init__``) of every
public class defined in profrobot, has an annotation. ``mypy`` (``[tool.mypy]`` in
``pyproject.toml``) then checks callers against them: the type checker is strict on the public
surface. ``self`` / ``cls``, ``*args`` / ``**kwargs`` and ``__init__``'s return are exempt.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import profrobot


def _modules() -> list:
    return [profrobot] + [importlib.import_module(m.name)
                          for m in pkgutil.walk_packages(profrobot.__path__, "profrobot.")]


def _public_callables():
    """``(qualified name, function)`` for every function named in a module's ``__all__`` and every
    public method (and ``__init__``) of a class named there and defined in profrobot; each once."""
    seen: set[int] = set()
    for m in _modules():
        for n in getattr(m, "__all__", []):
            obj = getattr(m, n, None)
            if obj is None or id(obj) in seen or inspect.ismodule(obj):
                continue
            seen.add(id(obj))
            if inspect.isfunction(obj):
                yield f"{m.__name__}.{n}", obj
            elif inspect.isclass(obj) and obj.__module__.startswith("profrobot"):
                for an, a in vars(obj).items():
                    if an.startswith("_") and an != "__init__":
                        continue
                    f = a.__func__ if isinstance(a, (classmethod, staticmethod)) else a
                    if inspect.isfunction(f):
                        yield f"{m.__name__}.{n}.{an}", f


def _unannotated() -> tuple[int, list[str], list[str]]:
    """(parameters counted, parameters without an annotation, functions without a return one)."""
    total, missing, noret = 0, [], []
    for name, fn in _public_callables():
        try:
            sig = inspect.signature(fn)
        except (TypeError, ValueError):
            continue
        for p in sig.parameters.values():
            if p.name in ("self", "cls") or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            total += 1
            if p.annotation is inspect.Parameter.empty:
                missing.append(f"{name}({p.name})")
        if sig.return_annotation is inspect.Signature.empty and not name.endswith("__init__"):
            noret.append(name)
    return total, missing, noret


def test_every_public_parameter_and_return_is_annotated():
    total, missing, noret = _unannotated()
    assert total > 1000, f"only {total} public parameters found: the walk over the package missed modules"
    assert not missing, f"{len(missing)} of {total} public parameters have no annotation:\n  " + "\n  ".join(missing)
    assert not noret, f"{len(noret)} public functions / methods have no return annotation:\n  " + "\n  ".join(noret)
