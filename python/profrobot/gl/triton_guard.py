"""triton's LLVM beside Mesa's: triton's extension modules loaded with ``RTLD_DEEPBIND`` while a
shared libLLVM (Mesa's llvmpipe brings one) is mapped, so that they bind to their own copy."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import os
import sys
import types
from collections.abc import Sequence

__all__ = ["llvm_mapped", "install_triton_guard", "TritonDeepbind"]


def llvm_mapped() -> bool:
    """Whether a shared libLLVM (Mesa's llvmpipe brings one) is mapped into this process."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return b"libLLVM" in f.read()
    except OSError:
        return False


class _DeepbindLoader(importlib.abc.Loader):
    def __init__(self, inner):
        self.inner = inner

    def create_module(self, spec):
        flags = sys.getdlopenflags()
        sys.setdlopenflags(flags | os.RTLD_DEEPBIND)
        try:
            return self.inner.create_module(spec)
        finally:
            sys.setdlopenflags(flags)

    def exec_module(self, module):
        return self.inner.exec_module(module)


class TritonDeepbind(importlib.abc.MetaPathFinder):
    """Loads ``triton._C.*`` extension modules with ``RTLD_DEEPBIND`` while a libLLVM is mapped."""

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: types.ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if not fullname.startswith("triton._C."):
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader) or not llvm_mapped():
            return None
        spec.loader = _DeepbindLoader(spec.loader)
        return spec


def install_triton_guard() -> None:
    """Put :class:`TritonDeepbind` first on ``sys.meta_path`` (once; Linux only). Without a
    libLLVM in the process, or once triton is imported, it changes nothing."""
    if not hasattr(os, "RTLD_DEEPBIND") or not sys.platform.startswith("linux"):
        return
    if not any(isinstance(f, TritonDeepbind) for f in sys.meta_path):
        sys.meta_path.insert(0, TritonDeepbind())
