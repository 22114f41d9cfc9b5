"""The diagnosis's effects: :mod:`.base` defines what an effect is; every other module here holds effects.

A module of this package that defines ``EFFECTS`` (a tuple of :class:`~.base.Effect` classes) is
found by :func:`workbench.diagnose.library.registry` without any other registration; effects
of other packages register through the ``workbench.effects`` entry-point group (docs/diagnose.md,
"How to add an effect"). Nothing is imported here.
"""
