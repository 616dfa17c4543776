"""A package's public names imported on first use (PEP 562), so that importing one of its
modules, or a command line's ``--help``, does not load what the others need (numba,
SciPy, OpenCV, trimesh)."""

from __future__ import annotations

from importlib import import_module

__all__ = ["lazy_exports"]


def lazy_exports(package: str, modules: dict[str, tuple[str, ...]]):
    """``(__getattr__, __dir__, __all__)`` for the package ``package`` (its ``__name__``)
    whose names ``modules`` lists by relative module (``{".carve": ("carve", ...)}``):
    each is imported from its module when first asked for, then kept in the package.

    A name that is also one of the package's modules (``meshing.advancing_front``) is
    that module once it has been imported, as Python binds it: take such a function
    from its module."""
    module_of = {name: module for module, names in modules.items() for name in names}
    namespace = import_module(package).__dict__

    def __getattr__(name: str):
        if name not in module_of:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module_of[name], package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(module_of))

    return __getattr__, __dir__, sorted(module_of)
