"""Benchmarks for capture.gopro (run on demand: ``python bench/gopro_bench.py``).

1. Download throughput of ``GoPro.download`` (streamed, progress, resumable) from the loopback
   ``FakeGoPro`` against the peer ``urllib.request.urlretrieve`` of the same URL, same run.
2. Frame timestamps: ``video_timing`` (MP4 box reader, no decoding) against the peer
   OpenCV ``CAP_PROP_POS_MSEC`` read while decoding every frame.
"""

from __future__ import annotations

import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from capture.gopro import FakeGoPro, GoPro, video_timing, write_video


def _best(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        rng = np.random.default_rng(0)
        clip = write_video(d / "clip.mp4", (rng.integers(0, 255, (270, 480), np.uint8) for _ in range(600)), fps=240)
        blob = d / "big.mp4"
        blob.write_bytes(clip.read_bytes() * max(1, (200 << 20) // clip.stat().st_size))
        size = blob.stat().st_size
        with FakeGoPro(blob) as fake:
            cam = GoPro(host=fake.host, port=fake.port)
            url = f"http://{fake.host}:{fake.port}/videos/DCIM/100GOPRO/GX010001.MP4"

            def ours():
                out = d / "dl"
                if out.exists():
                    for f in out.iterdir():
                        f.unlink()
                cam.download("GX010001.MP4", out, progress=False)

            t_ours = _best(ours)
            t_peer = _best(lambda: urllib.request.urlretrieve(url, d / "peer.mp4"))
        print(f"download {size / 2**20:.0f} MiB: GoPro.download {size / t_ours / 2**20:.0f} MiB/s, "
              f"urlretrieve {size / t_peer / 2**20:.0f} MiB/s, ratio {t_peer / t_ours:.2f}x")

        import cv2

        def peer_ts():
            cap = cv2.VideoCapture(str(clip))
            ms = []
            while cap.read()[0]:
                ms.append(cap.get(cv2.CAP_PROP_POS_MSEC))
            return ms

        t_box = _best(lambda: video_timing(clip))
        t_cv = _best(peer_ts, repeat=1)
        print(f"timestamps of {len(video_timing(clip).pts)} frames: video_timing {t_box * 1e3:.2f} ms, "
              f"OpenCV POS_MSEC (decoding) {t_cv * 1e3:.0f} ms, ratio {t_cv / t_box:.0f}x")


if __name__ == "__main__":
    main()
