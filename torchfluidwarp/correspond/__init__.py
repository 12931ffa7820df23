"""Correspondence: the points of a morph found from the two pictures, with no point files.

* :func:`~torchfluidwarp.correspond.faces.detect_face_points`: 63 face landmarks from mediapipe's face mesh
  (the optional ``faces`` extra: ``pip install "torchfluidwarp[faces]"``).
* :func:`~torchfluidwarp.correspond.features.match_features`: matched SIFT features (kornia; no weights),
  filtered by RANSAC and by their neighbours, thinned to a well-spread subset.
* :func:`~torchfluidwarp.correspond.auto.auto_points`: faces when both images show one, features otherwise,
  with :func:`~torchfluidwarp.correspond.auto.border_points` anchors.
* :func:`~torchfluidwarp.correspond.refine.refine_points`: the pixels add pairs to sparse ones, through a flow
  fitted to the images (:func:`~torchfluidwarp.control.images.fit_images`) with the pairs as anchors.

Every point is ``(x, y)`` in pixels with pixel centres at integers, as everywhere in the library.
"""

from torchfluidwarp.correspond.auto import MatchMode, auto_points, border_points
from torchfluidwarp.correspond.faces import FACE_LANDMARKS, FACE_MESH_INDICES, detect_face_points
from torchfluidwarp.correspond.features import match_features
from torchfluidwarp.correspond.refine import refine_points

__all__ = [
    "FACE_LANDMARKS",
    "FACE_MESH_INDICES",
    "MatchMode",
    "auto_points",
    "border_points",
    "detect_face_points",
    "match_features",
    "refine_points",
]
