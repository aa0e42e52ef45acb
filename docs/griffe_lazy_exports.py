"""A griffe extension for the API reference (mkdocs.yml loads it).

``raytrax/__init__.py`` resolves its public names on first use (PEP 562
``__getattr__``), so griffe's static analysis sees no ``raytrax.render``. This
extension imports the package, looks up every name of ``raytrax.__all__`` and adds
it to the statically loaded package as an alias of wherever the object is defined
today, so the pages can say ``::: raytrax.render`` whichever module holds it.

It also turns the Sphinx roles of the docstrings (:class:`~raytrax.Scene`) into
plain code spans, which Markdown renders.
"""

from __future__ import annotations

import importlib
import re
import types

import griffe

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj|const):`(~?)([^`]+)`")


def _plain_role(m: re.Match) -> str:
    target = m[2].rsplit(".", 1)[-1] if m[1] else m[2]
    return f"`{target}`"


def _strip_roles(obj, seen: set) -> None:
    if obj.is_alias or id(obj) in seen:
        return
    seen.add(id(obj))
    if obj.docstring is not None:
        obj.docstring.value = _ROLE.sub(_plain_role, obj.docstring.value)
    for member in obj.members.values():
        _strip_roles(member, seen)


class LazyExports(griffe.Extension):
    def _add_aliases(self, pkg) -> None:
        if pkg.path != "raytrax":
            return
        _strip_roles(pkg, set())
        runtime = importlib.import_module("raytrax")
        for name in runtime.__all__:
            if name.startswith("_"):
                continue
            obj = getattr(runtime, name)
            module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
            if isinstance(obj, types.ModuleType) or not module or not qualname:
                continue
            target = f"{module}.{qualname}"
            if target == f"raytrax.{name}":
                continue
            # Replaces a submodule of the same name too: at runtime ``raytrax.fit`` is the function.
            pkg.set_member(name, griffe.Alias(name, target, parent=pkg))

    def on_package(self, *, pkg, **kwargs) -> None:  # griffe >= 1.14
        self._add_aliases(pkg)

    def on_package_loaded(self, *, pkg, **kwargs) -> None:  # older griffe
        self._add_aliases(pkg)
