"""Concurrent generation and display (thesis 3.3.1, 3.5.4, Fig. 3.1).

:class:`GeometryWorker` runs a :class:`ClipBoxPipeline` on a geometry thread while the
renderer draws; complete, mutually consistent level sets are handed over through a
double buffer and a sync flag, swapped at the start of a frame.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from jaxgfx._src.terrain.clipbox import NestedClipBoxes
from jaxgfx._src.terrain.pipeline import ClipBoxPipeline

__all__ = ["GeometryWorker"]


class GeometryWorker:
    """Geometry thread that rebuilds Clip-Boxes while the renderer draws (Fig. 3.1).

    The worker owns the back buffer and the renderer the front buffer.  When a
    rebuilt set of levels is completely written to the back buffer, the worker
    raises the sync flag and waits; the renderer's :meth:`acquire` swaps the two
    buffers and clears the flag at the start of a frame.  The renderer therefore
    only ever sees complete, mutually consistent meshes, and the worker never
    writes a buffer that is being drawn.

    A buffer is ``dict(stamp=(2,) int64 [generation at start, at end],
    levels=[per level dict(vertices, normals, faces, visible, origin, checksum)])``.

    Args:
        pipeline: the :class:`ClipBoxPipeline`.
        viewer: initial integer viewer position.
    """

    def __init__(self, pipeline: ClipBoxPipeline, viewer):
        self.pipeline = pipeline
        self.state = pipeline.init(viewer)
        self._viewer = np.asarray(viewer, np.int64)
        self._buffers = [self._new_buffer(), self._new_buffer()]
        self._write(self._buffers[0], self.state, 0)
        self._front = 0
        self._sync = False
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.generation = 0
        self.swaps = 0
        self.stats: list[dict] = []

    @staticmethod
    def _new_buffer() -> dict:
        return dict(stamp=np.full(2, -1, np.int64), levels=[])

    def _write(self, buf: dict, state: NestedClipBoxes, gen: int) -> None:
        buf["stamp"][0] = gen  # written first ...
        views = self.pipeline.views(state)
        if len(buf["levels"]) != len(views):
            buf["levels"] = [dict() for _ in views]
        for dst, src in zip(buf["levels"], views):
            for k, v in src.items():
                if k in dst and dst[k].shape == v.shape and dst[k].dtype == v.dtype:
                    np.copyto(dst[k], v)  # in place: tearing would be visible
                else:
                    dst[k] = v.copy()
            dst["checksum"] = float(np.sum(src["vertices"], dtype=np.float64))
            dst["generation"] = gen
        buf["stamp"][1] = gen  # ... and last

    def published(self) -> tuple[int, NestedClipBoxes]:
        """The newest written generation and its Clip-Box state, read together."""
        with self._cv:
            return self.generation, self.state

    def set_viewer(self, viewer) -> None:
        """Called by the renderer: where the geometry should follow."""
        self._viewer = self.pipeline._check_viewer(viewer)

    def start(self) -> GeometryWorker:
        self._thread = threading.Thread(target=self._run, name="clipbox-geometry", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                state, stats = self.pipeline.update(self.state, self._viewer)
                if not stats:
                    time.sleep(0.001)
                    continue
                gen = self.generation + 1
                self._write(self._buffers[1 - self._front], state, gen)
                with self._cv:
                    # state and generation change together: published() never sees a
                    # state whose buffer is not written yet.
                    self.state = state
                    self.generation = gen
                    self.stats.append(stats)
                    self._sync = True
                    while self._sync and not self._stop.is_set():
                        self._cv.wait(0.05)
        except BaseException as err:  # surfaced to the renderer in acquire()
            self._error = err

    def acquire(self) -> dict:
        """Renderer side, once per frame: swap in the newest complete buffer if flagged."""
        if self._error is not None:
            raise RuntimeError("geometry worker failed") from self._error
        with self._cv:
            if self._sync:
                self._front = 1 - self._front
                self._sync = False
                self.swaps += 1
                self._cv.notify_all()
            return self._buffers[self._front]
