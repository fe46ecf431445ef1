"""Offline ingest of GoPro MP4 recordings: frames with per-frame container timestamps.

GoPro splits long recordings into ~4 GB chapters named ``GXccnnnn.MP4`` (``cc`` the chapter,
``nnnn`` the file number; ``GH`` for AVC). :func:`read_video` joins the chapters of a recording
into one continuous clock: chapter ``k`` starts where chapter ``k-1``'s track duration ends.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from capture.gopro.mp4 import MP4Error, video_timing

_CHAPTER = re.compile(r"^(G[HX])(\d{2})(\d{4})\.(MP4|mp4)$")


def chapter_paths(path) -> list[Path]:
    """The chapters of the recording that ``path`` belongs to, in order.

    A GoPro name ``GXccnnnn.MP4`` gives every existing ``GX..nnnn.MP4`` in the same folder with
    a chapter number ``>= cc``, stopping at the first missing chapter; any other name gives
    ``[path]``.

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video file not found: {path}")
    m = _CHAPTER.match(path.name)
    if not m:
        return [path]
    prefix, first, number, ext = m.group(1), int(m.group(2)), m.group(3), m.group(4)
    out = []
    for cc in range(first, 100):
        p = path.with_name(f"{prefix}{cc:02d}{number}.{ext}")
        if not p.is_file():
            break
        out.append(p)
    return out


@dataclass
class Video:
    """A recording (one or more chapters) with exact per-frame timestamps.

    Attributes
    ----------
    paths : list of Path
        The chapter files, in order.
    t_s : ndarray of float64, shape (N,)
        Presentation time of every frame in seconds on the camera's clock, chapters joined
        (0 at the first frame of the first chapter).
    fps : Fraction
        Nominal frame rate (frames per second) from the container, e.g. ``Fraction(240000, 1001)``.
    width, height : int
        Frame size in pixels.
    chapter_start : ndarray of int64, shape (n_chapters,)
        Index of the first frame of each chapter.
    """

    paths: list[Path]
    t_s: np.ndarray
    fps: Fraction
    width: int
    height: int
    chapter_start: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return len(self.t_s)

    @property
    def fps_num(self) -> int:
        """Frame-rate numerator (``fps = fps_num / fps_den``)."""
        return self.fps.numerator

    @property
    def fps_den(self) -> int:
        """Frame-rate denominator."""
        return self.fps.denominator

    def frames(self, *, gray: bool = False) -> Iterator[tuple[int, float, np.ndarray]]:
        """Decode the frames one at a time (bounded memory).

        Yields
        ------
        (index, t_s, image)
            Frame index, its presentation time (s) and the image, ``(H, W, 3)`` BGR uint8 or
            ``(H, W)`` uint8 when ``gray``.

        Raises
        ------
        MP4Error
            When a chapter decodes to a different number of frames than its container lists.
        """
        i = 0
        for k, p in enumerate(self.paths):
            cap = cv2.VideoCapture(str(p))
            if not cap.isOpened():
                raise MP4Error(f"{p}: OpenCV cannot open the video")
            n_expected = (self.chapter_start[k + 1] if k + 1 < len(self.paths) else self.n_frames) - i
            n = 0
            try:
                while True:
                    ok, img = cap.read()
                    if not ok:
                        break
                    if n >= n_expected:
                        raise MP4Error(f"{p}: decoder gives more frames than the {n_expected} the container lists")
                    if gray and img.ndim == 3:
                        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                    yield i, float(self.t_s[i]), img
                    i += 1
                    n += 1
            finally:
                cap.release()
            if n != n_expected:
                raise MP4Error(f"{p}: decoded {n} frames, the container lists {n_expected}")

    def __iter__(self):
        return self.frames()


def read_video(path) -> Video:
    """Open a GoPro recording (chapters joined) with per-frame container timestamps.

    Parameters
    ----------
    path : str or Path
        The MP4 file, or the first chapter of a chaptered recording.

    Returns
    -------
    Video
        Timestamps and frame rate are read from the MP4 boxes (``mdhd``/``stts``/``ctts``/``elst``),
        not assumed; frames are decoded lazily by :meth:`Video.frames`.

    Raises
    ------
    FileNotFoundError, MP4Error
    """
    paths = chapter_paths(path)
    t_parts, starts, t0 = [], [], 0.0
    fps = width = height = None
    n = 0
    for p in paths:
        timing = video_timing(p)
        if fps is None:
            fps, width, height = timing.fps, timing.width, timing.height
        starts.append(n)
        t_parts.append(t0 + timing.t_s)
        t0 += timing.duration / timing.timescale
        n += len(timing.pts)
    return Video(paths=paths, t_s=np.concatenate(t_parts), fps=fps, width=width, height=height,
                 chapter_start=np.asarray(starts, np.int64))


def write_video(path, frames, fps: float) -> Path:
    """Write frames to an MP4 (``mp4v``) with OpenCV; used by the simulator and tests.

    Parameters
    ----------
    path : str or Path
        Output file; missing parent folders are created.
    frames : iterable of ndarray
        ``(H, W, 3)`` BGR or ``(H, W)`` grey uint8 images, all the same size (px); a
        ``(T, H, W)`` or ``(T, H, W, 3)`` array is such an iterable. No frames: no file.
    fps : float
        Frame rate written to the container (frames per second).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        When OpenCV cannot open a writer for ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = None
    try:
        for img in frames:
            if img.ndim == 2:
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            if writer is None:
                h, w = img.shape[:2]
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
                if not writer.isOpened():
                    raise OSError(f"cannot open a video writer for {path}")
            writer.write(img)
    finally:
        if writer is not None:
            writer.release()
    return path
