"""The quality of a morph, measured from its maps and frames: folds, landmark errors, ghosting, seams, path smoothness.

Each measure is a pure function of tensors, so it applies to any morph that has backward coordinate maps (the
fluid's :class:`~torchfluidwarp.morph.MorphResult`, or a thin-plate-spline or Delaunay baseline), and
:func:`morph_report` gathers them for a :class:`~torchfluidwarp.morph.MorphResult` in one streamed pass:

* **folds**: map pixels whose Jacobian determinant is ``<= 0`` (:func:`folded_pixels`, per frame);
* **landmark error** at the last frame (``result.error``, in the frames' pixels) and the **held-out error**: where
  A's held-out points show in the last frame against B's (:func:`end_error`);
* **ghosting**: how far apart A's and B's copies of a point show in the middle frame (:func:`ghosting`), and
  the same seen in the pixels with no points: the local displacement between A and B warped to the middle frame
  (:func:`image_ghosting`);
* **seam figure**: a high quantile of the map's second derivative (:func:`seam_figure`);
* **border seam**: whether a picture's border shows as a line in a frame, or its edge pixels are smeared beyond
  it (:func:`border_seam`);
* **path smoothness**: the distance between neighbouring frames, its total and its variance
  (:func:`path_distances`, :func:`path_smoothness`): a perceptual-path-length-style measure without a network.

Conventions: maps ``(N, H, W, 2)`` are backward maps (output pixel -> source pixel), ``(x, y)``, in pixels with
pixel centres at integers, as :func:`~torchfluidwarp.warp.warp_image` reads them. A point "shows" in a frame at the
``y`` with ``map(y) = p``, found by Newton's method on the bilinearly read map (:func:`locate`); a point that does
not converge to within ``tolerance`` source pixels (carried out of the frame, say) is reported as not located.
"""

from torchfluidwarp.metrics.edges import BorderSeam, border_seam
from torchfluidwarp.metrics.ghost import GHOST_SIDE, GHOST_TEXTURE, GHOST_WINDOW, image_ghosting
from torchfluidwarp.metrics.maps import SEAM_QUANTILE, folded_pixels, seam_figure
from torchfluidwarp.metrics.path import PathKind, path_distances, path_smoothness
from torchfluidwarp.metrics.points import (
    LOCATE_TOLERANCE,
    end_error,
    ghosting,
    invert_map_at,
    landmark_error,
    locate,
    read_map,
)
from torchfluidwarp.metrics.report import Morph, morph_folds, morph_path, morph_report, report_frames

__all__ = [
    "BorderSeam",
    "border_seam",
    "GHOST_SIDE",
    "GHOST_TEXTURE",
    "GHOST_WINDOW",
    "LOCATE_TOLERANCE",
    "Morph",
    "PathKind",
    "SEAM_QUANTILE",
    "end_error",
    "folded_pixels",
    "ghosting",
    "image_ghosting",
    "invert_map_at",
    "landmark_error",
    "locate",
    "morph_folds",
    "morph_path",
    "morph_report",
    "report_frames",
    "path_distances",
    "path_smoothness",
    "read_map",
    "seam_figure",
]
