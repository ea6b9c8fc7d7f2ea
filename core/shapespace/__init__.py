"""The space of human body shapes (Allen, Curless, Popović 2003, §4–5).

- :class:`ShapeModel` (per-sex and joint PCA spaces with feature maps): synthesis from features,
  PCA weights or a seed; projection; editing; weight from volume; save/:func:`load_model`.
- :func:`build_model` — a model from a folder of fitted bodies and a feature table.
- :func:`fit_pca`, :class:`PCA`, :class:`FeatureMap`, :func:`fit_feature_map` — the parts.
- :class:`OutOfRangeError` (code ``out_of_range``) for requests outside a model's range.
"""

from core.shapespace.build import build_model, read_bodies, read_features
from core.shapespace.errors import ModelFormatError, OutOfRangeError
from core.shapespace.features import FeatureMap, fit_feature_map
from core.shapespace.model import (
    DEFAULT_MODEL,
    ShapeModel,
    Space,
    body_height,
    body_volume,
    default_model,
    load_model,
)
from core.shapespace.pca import PCA, fit_pca, from_model_frame, rigid_align, to_model_frame

__all__ = [
    "DEFAULT_MODEL",
    "PCA",
    "FeatureMap",
    "ModelFormatError",
    "OutOfRangeError",
    "ShapeModel",
    "Space",
    "body_height",
    "body_volume",
    "build_model",
    "default_model",
    "fit_feature_map",
    "fit_pca",
    "from_model_frame",
    "load_model",
    "read_bodies",
    "read_features",
    "rigid_align",
    "to_model_frame",
]
