"""Friction laws as objects, one module per law, in one registry (registry): each law declares its plant-file keys
with units, defaults and value rules, its internal states, its force and state derivatives as CasADi expressions,
and what selection, compensation and results need of it.  The viscous term (fv, or fv_pos/fv_neg) belongs to every
law (viscous).  docs/friction.md has the equations and references."""

__all__: list[str] = []
