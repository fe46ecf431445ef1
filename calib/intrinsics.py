"""Camera intrinsics: checkerboard / ChArUco calibration with OpenCV, for the GoPro and for the
event camera (a blinking pattern accumulated from events into an image).

Pixel coordinates follow ``docs/conventions.md``: (u, v) = (x, y), pixel centres at integers; the
camera frame is X right, Y down, Z forward. Distances are in metres.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np


class CalibrationError(ValueError):
    """Calibration impossible with the given data (message says why)."""


@dataclass
class Intrinsics:
    """Pinhole camera with OpenCV's distortion model.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Camera matrix (fx, fy, cx, cy in pixels).
    dist : ndarray, shape (5,) or more
        Distortion coefficients ``(k1, k2, p1, p2, k3, ...)``.
    width, height : int
        Image size in pixels.
    rms_px : float
        RMS reprojection error of the calibration (pixels).
    """

    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    rms_px: float = 0.0

    @property
    def focal_px(self) -> float:
        """Mean focal length ``(fx + fy) / 2`` in pixels."""
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    def project(self, X_m, rvec=None, tvec=None) -> np.ndarray:
        """Project 3-D points (N, 3) in metres (camera frame unless ``rvec``/``tvec``) to pixels (N, 2)."""
        X = np.asarray(X_m, np.float64).reshape(-1, 1, 3)
        r = np.zeros(3) if rvec is None else np.asarray(rvec, np.float64)
        t = np.zeros(3) if tvec is None else np.asarray(tvec, np.float64)
        uv, _ = cv2.projectPoints(X, r, t, self.K, self.dist)
        return uv.reshape(-1, 2)

    def rays(self, uv_px) -> np.ndarray:
        """Undistorted normalised rays ``(x, y, 1)`` (N, 3) through pixels ``uv_px`` (N, 2)."""
        uv = np.asarray(uv_px, np.float64).reshape(-1, 1, 2)
        xy = cv2.undistortPoints(uv, self.K, self.dist).reshape(-1, 2)
        return np.column_stack([xy, np.ones(len(xy))])

    def to_dict(self) -> dict:
        """JSON-able dict (for the session attrs)."""
        return {"K": self.K.tolist(), "dist": np.ravel(self.dist).tolist(), "width": int(self.width),
                "height": int(self.height), "rms_px": float(self.rms_px)}

    @classmethod
    def from_dict(cls, d: dict) -> Intrinsics:
        """Rebuild from :meth:`to_dict` output."""
        return cls(K=np.asarray(d["K"], float).reshape(3, 3), dist=np.asarray(d["dist"], float),
                   width=int(d["width"]), height=int(d["height"]), rms_px=float(d.get("rms_px", 0.0)))


def checkerboard_points(pattern_size: tuple[int, int], square_m: float) -> np.ndarray:
    """Board coordinates (N, 3) in metres of the inner corners, row by row (z = 0).

    ``pattern_size`` is (corners per row, corners per column), as OpenCV counts them.
    """
    cols, rows = pattern_size
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float64) * square_m
    return np.column_stack([g, np.zeros(len(g))])


def find_checkerboard(image: np.ndarray, pattern_size: tuple[int, int]) -> np.ndarray | None:
    """Inner-corner pixel positions (N, 2) of a checkerboard, or ``None`` when not found.

    Uses OpenCV's sector-based detector (sub-pixel accurate); corners come row by row in the
    order of :func:`checkerboard_points` (OpenCV may return the board rotated by 180 degrees, which
    calibration handles).
    """
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    ok, corners = cv2.findChessboardCornersSB(img, tuple(pattern_size), flags=cv2.CALIB_CB_EXHAUSTIVE)
    return corners.reshape(-1, 2).astype(np.float64) if ok else None


def calibrate_from_points(object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray],
                          image_size: tuple[int, int], *, fix_k3: bool = True) -> Intrinsics:
    """Intrinsics from matched board points of several views.

    Parameters
    ----------
    object_points : sequence of ndarray, each (N_i, 3)
        Board coordinates in metres.
    image_points : sequence of ndarray, each (N_i, 2)
        Detected pixels.
    image_size : (width, height)
        Image size in pixels.
    fix_k3 : bool
        Keep the 6th-order radial term at 0 (recommended for linear-lens GoPro footage and few views).

    Raises
    ------
    CalibrationError
        With fewer than 3 views.
    """
    if len(image_points) < 3:
        raise CalibrationError(f"need at least 3 views of the board, got {len(image_points)}")
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    img = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in image_points]
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, tuple(int(v) for v in image_size), None, None, flags=flags)
    return Intrinsics(K=K, dist=dist.ravel(), width=int(image_size[0]), height=int(image_size[1]), rms_px=float(rms))


def calibrate_checkerboard(images: Iterable[np.ndarray], pattern_size: tuple[int, int], square_m: float,
                           *, min_views: int = 3) -> tuple[Intrinsics, list[int]]:
    """Detect a checkerboard in each image and calibrate.

    Returns
    -------
    intrinsics : Intrinsics
    used : list of int
        Indices of the images where the board was found.

    Raises
    ------
    CalibrationError
        When the board is found in fewer than ``min_views`` images.
    """
    obj = checkerboard_points(pattern_size, square_m)
    pts, used, size = [], [], None
    for i, img in enumerate(images):
        size = (img.shape[1], img.shape[0])
        c = find_checkerboard(img, pattern_size)
        if c is not None:
            pts.append(c)
            used.append(i)
    if len(pts) < max(3, min_views):
        raise CalibrationError(f"checkerboard {pattern_size} found in {len(pts)} images, need {max(3, min_views)}")
    return calibrate_from_points([obj] * len(pts), pts, size), used


def charuco_board(squares: tuple[int, int] = (7, 5), square_m: float = 0.04, marker_m: float = 0.03,
                  dictionary: str = "DICT_4X4_50"):
    """An OpenCV ChArUco board (``squares`` = squares along x, y)."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    return cv2.aruco.CharucoBoard(tuple(squares), float(square_m), float(marker_m), d)


def calibrate_charuco(images: Iterable[np.ndarray], board, *, min_corners: int = 6) -> tuple[Intrinsics, list[int]]:
    """Detect a ChArUco board (partial views allowed) in each image and calibrate.

    Parameters
    ----------
    images : iterable of ndarray
        Gray or BGR images.
    board : cv2.aruco.CharucoBoard
        See :func:`charuco_board`.
    min_corners : int
        Views with fewer detected ChArUco corners are skipped.

    Returns
    -------
    (Intrinsics, indices of the images used)
    """
    det = cv2.aruco.CharucoDetector(board)
    obj, pts, used, size = [], [], [], None
    for i, img in enumerate(images):
        size = (img.shape[1], img.shape[0])
        cc, ci, _, _ = det.detectBoard(img)
        if cc is None or len(cc) < min_corners:
            continue
        o, p = board.matchImagePoints(cc, ci)
        obj.append(o.reshape(-1, 3))
        pts.append(p.reshape(-1, 2))
        used.append(i)
    if len(pts) < 3:
        raise CalibrationError(f"ChArUco board found in {len(pts)} images, need 3")
    return calibrate_from_points(obj, pts, size), used


def accumulate_events(events: np.ndarray, width: int, height: int, *, clip_percentile: float = 99.0) -> np.ndarray:
    """Event-count image (uint8) for calibrating the event camera with a blinking pattern.

    A pattern blinking on a screen (white squares <-> black) fires events on its bright squares
    only; the count image then shows the pattern, and :func:`find_checkerboard` finds its corners.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Events of one static pose of the pattern (a few blinks).
    width, height : int
        Sensor size in pixels.
    clip_percentile : float
        Counts above this percentile saturate (hot pixels).

    Returns
    -------
    ndarray of uint8, shape (height, width)
    """
    counts = np.bincount(events["y"].astype(np.int64) * width + events["x"], minlength=width * height)
    counts = counts[: width * height].reshape(height, width).astype(np.float32)
    top = np.percentile(counts[counts > 0], clip_percentile) if np.any(counts > 0) else 1.0
    img = np.clip(counts / max(top, 1e-6), 0, 1) * 255
    return cv2.GaussianBlur(img, (3, 3), 0).astype(np.uint8)
