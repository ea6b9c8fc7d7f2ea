"""Body measurements (ISO 7250-1 / ANSUR II) of any body in template vertex order.

- :func:`measure` — heights, lengths, breadths, depths, circumferences and mass of a body,
  keyed by ANSUR II column names, in metres (``weightkg`` in kilograms).
- :data:`MEASUREMENTS` — name -> (kind, unit, definition, ANSUR column).
- Geometry used by them, usable on any closed triangle mesh: :func:`plane_section`,
  :func:`convex_perimeter`, :func:`section_circumference`, :func:`mesh_volume`.
"""

from core.measure.body import DEFAULT_DENSITY, measure
from core.measure.definitions import MEASUREMENTS, Measurement
from core.measure.sections import (
    MeshTopology,
    Section,
    convex_perimeter,
    mesh_volume,
    plane_basis,
    plane_section,
    section_circumference,
)

__all__ = [
    "DEFAULT_DENSITY",
    "MEASUREMENTS",
    "Measurement",
    "MeshTopology",
    "Section",
    "convex_perimeter",
    "measure",
    "mesh_volume",
    "plane_basis",
    "plane_section",
    "section_circumference",
]
