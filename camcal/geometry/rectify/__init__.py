"""Rectification of two and of N views: calibrated, Nozick 2011 N-view, Hartley 1999.

Rectified views share one image plane whose rows are parallel to the line
of camera centres, so a scene point appears on the same row in every view.
camcal stores, per camera, ``rectification = {H, K_rect, image_size}``
where ``H`` maps UNDISTORTED pixels of the original camera to rectified
pixels: a rectified image is sampled at ``distort(H^-1 x_r)``, undistortion
and rectification in ONE ``cv2.remap`` (:class:`RectifyWarper`, built on
:func:`camcal.geometry.remap.build_maps`).

Conventions (DESIGN.md)
-----------------------
- ``x ~ K [R | -R c] X``, ``R`` world -> camera, camera axes x right,
  y down, z forward; pixel (0, 0) is the centre of the top-left pixel.
- Correspondences (:data:`Matches`) map a pair of camera names
  ``(a, b)`` to two arrays of shape (n, 2): the same scene points seen in
  the ORIGINAL (distorted) images of ``a`` and ``b``, in pixels.

Methods
-------
- :func:`rectify_calibrated` (``"camera"``): the centres' line is fitted,
  one common rotation ``R_rect`` (x along the line, the rotation nearest the
  cameras' mean rotation: ``cv2.stereoRectify``'s choice for two cameras)
  and one shared ``K_rect`` (square pixels, the
  cameras' mean focal length, principal point and size chosen by
  ``alpha``), ``H_i = K_rect R_rect R_i^T K_i^-1`` (Fusiello et al. 2000,
  generalised to N cameras as in Nozick 2011).
- :func:`rectify_Nozick2011`: the calibrated start, then a joint
  refinement of every camera's rotation and focal length minimising the
  vertical disparity of every correspondence between all views.
- :func:`rectify_Hartley1999`: two views, no calibration (only K and
  distortion, to undistort): robust F (RANSAC, OpenCV), the second
  epipole sent to infinity along x, and the matching transform of the first
  image that minimises the disparity.

Fisheye lenses (``kannala-brandt``): pixels are taken through their rays
(:meth:`~camcal.model.distortion.Distortion.rays_from_pixels`), so
``H`` acts on ``K r``, defined beyond 90 degrees from the camera's axis.
A pinhole rectified image cannot hold rays near 90 degrees from its axis
(it stretches a ray at ``theta`` by ``1 / cos^2 theta``), so its field of
view is capped, as ``camcal undistort`` caps it: ``max_fov_deg`` (full
angle about the rectified viewing direction; by default 120 degrees when a
camera has a fisheye lens, no cap otherwise). The rotations are those of
``cv2.fisheye.stereoRectify``; its new camera matrix (focal chosen by
``balance`` / ``fov_scale``) differs from ``K_rect`` (mean focal, frame by
``alpha`` inside the cap).

Modules: :mod:`~camcal.geometry.rectify.model` (results, metrics),
:mod:`~camcal.geometry.rectify.frame` (the steps the methods share),
:mod:`~camcal.geometry.rectify.methods` (the methods and :func:`rectify`),
:mod:`~camcal.geometry.rectify.maps` (the warp and SIFT matches on image arrays).

Metrics: vertical disparity RMS and max per pair on correspondences
(:func:`vertical_disparity`), Mallon & Whelan's orthogonality and
aspect-ratio distortion, and the shares of the original image kept and of
the rectified image covered (:func:`image_deformation`).

References
----------
Fusiello, A., Trucco, E. & Verri, A. (2000). A compact algorithm for
rectification of stereo pairs. Machine Vision and Applications 12(1).
Hartley, R. I. (1999). Theory and practice of projective rectification.
International Journal of Computer Vision 35(2), 115-127.
Mallon, J. & Whelan, P. F. (2005). Projective rectification from the
fundamental matrix. Image and Vision Computing 23(7), 643-650.
Nozick, V. (2011). Multiple view image rectification. Proc. IEEE-ISAS
2011, International Symposium on Access Spaces, 277-282.
Markley, F. L., Cheng, Y., Crassidis, J. L. & Oshman, Y. (2007). Averaging
quaternions. Journal of Guidance, Control, and Dynamics 30(4), 1193-1197.
Lowe, D. G. (2004). Distinctive image features from scale-invariant
keypoints. IJCV 60(2) (SIFT and the ratio test).
"""


from camcal.geometry.rectify.maps import RectifyWarper, match_images
from camcal.geometry.rectify.methods import rectify, rectify_calibrated, rectify_Hartley1999, rectify_Nozick2011
from camcal.geometry.rectify.model import (
    METHODS,
    CentresOffLineWarning,
    ImageDeformation,
    Matches,
    PairDisparity,
    RectificationResult,
    image_deformation,
    vertical_disparity,
)

__all__ = [
    "METHODS",
    "CentresOffLineWarning",
    "ImageDeformation",
    "Matches",
    "PairDisparity",
    "RectificationResult",
    "RectifyWarper",
    "image_deformation",
    "match_images",
    "rectify",
    "rectify_Hartley1999",
    "rectify_Nozick2011",
    "rectify_calibrated",
    "vertical_disparity",
]
