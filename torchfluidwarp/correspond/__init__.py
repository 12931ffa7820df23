"""Correspondence: the points of a morph found from the two pictures, with no point files.

* :func:`~torchfluidwarp.correspond.faces.find_faces`: every face in a photograph (whole portraits, any size,
  grey or colour, tilted), with mediapipe's face detectors and face mesh (the optional ``faces`` extra:
  ``pip install "torchfluidwarp[faces]"``); :func:`~torchfluidwarp.correspond.faces.detect_face_points`: the
  63 landmarks of one of them.
* :func:`~torchfluidwarp.correspond.features.match_features`: matched SIFT features (kornia; no weights),
  filtered by RANSAC and by their neighbours, thinned to a well-spread subset.
* :func:`~torchfluidwarp.correspond.auto.auto_points`: faces when both images show one, features otherwise (the
  pixels where too few match), with :func:`~torchfluidwarp.correspond.auto.border_points` anchors, paired as
  :func:`~torchfluidwarp.correspond.auto.border_pairs` says (frame on frame only where the frames correspond);
  :func:`~torchfluidwarp.correspond.auto.find_points`: the same, with which matcher it used and why.
* :func:`~torchfluidwarp.correspond.auto.find_each_face`: the same face landmarks in each of several pictures
  (a morph through them, their average).
* :func:`~torchfluidwarp.correspond.refine.refine_points`: the pixels add pairs to sparse ones, through a flow
  fitted to the images (:func:`~torchfluidwarp.control.images.fit_images`) with the pairs as anchors.
* :func:`~torchfluidwarp.correspond.halfway.halfway_alignment`: what the marks leave open, aligned by the pixels
  on the morph's middle frame (local correlation, coarse to fine), as :class:`HalfwaySettings` say; the natural
  morph does this by default.

Every point is ``(x, y)`` in pixels with pixel centres at integers, as everywhere in the library.
"""

from torchfluidwarp.correspond.auto import (
    FoundPoints,
    MatchMode,
    MatchNotice,
    Note,
    auto_points,
    border_pairs,
    border_points,
    find_each_face,
    find_points,
)
from torchfluidwarp.correspond.faces import (
    FACE_LANDMARKS,
    FACE_MESH_INDICES,
    Face,
    NoFaceFound,
    detect_face_points,
    find_faces,
)
from torchfluidwarp.correspond.features import match_features
from torchfluidwarp.correspond.halfway import HalfwayAlignment, HalfwaySettings, halfway_alignment
from torchfluidwarp.correspond.refine import refine_points

__all__ = [
    "FACE_LANDMARKS",
    "FACE_MESH_INDICES",
    "Face",
    "FoundPoints",
    "HalfwayAlignment",
    "HalfwaySettings",
    "MatchMode",
    "MatchNotice",
    "NoFaceFound",
    "Note",
    "auto_points",
    "border_pairs",
    "border_points",
    "detect_face_points",
    "find_faces",
    "find_each_face",
    "find_points",
    "halfway_alignment",
    "match_features",
    "refine_points",
]
