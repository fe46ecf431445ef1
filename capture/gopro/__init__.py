"""GoPro over wired USB (Open GoPro HTTP API), its loopback fake, and MP4 ingest.

- :class:`GoPro`: record, settings, keep-alive, media list, download with progress and resume.
- :class:`FakeGoPro`: loopback HTTP server with the same endpoints, serving a simulated MP4.
- :func:`read_video`: frames (lazy) with per-frame container timestamps and the exact frame rate.
- :func:`write_video`: frames to an MP4 (the simulator's videos, test clips).
"""

from capture.gopro.client import (
    CameraBusy,
    CameraUnreachable,
    DownloadError,
    GoPro,
    GoProError,
    MediaFile,
    MediaNotFound,
    address_from_serial,
)
from capture.gopro.fake import FakeGoPro
from capture.gopro.mp4 import MP4Error, video_timing
from capture.gopro.video import Video, chapter_paths, read_video, write_video

__all__ = [
    "GoPro", "FakeGoPro", "MediaFile", "address_from_serial", "read_video", "Video", "chapter_paths",
    "video_timing", "write_video", "GoProError", "CameraUnreachable", "CameraBusy", "MediaNotFound",
    "DownloadError", "MP4Error",
]
