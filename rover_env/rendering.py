"""Offscreen OpenGL rendering of a RoverSim's model: the forward camera (colour, metric
depth, pedestrian segmentation) and the chase view, one context per process.

The context is made on first use, in the process that renders: EGL state does not survive
``fork()``, and a renderer cannot be pickled into a worker.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable
from typing import NamedTuple

import mujoco
import numpy as np

from rover_env.worlds.spec import GROUP_MARKER

# Mesa's llvmpipe (the headless EGL renderer) rasterises on a pool of one thread per core by
# default. A 96x96 camera frame is too small to split: the pool's hand-offs cost more than
# they save, and on a 2-core machine its threads compete with the av-daemon and the other
# envs. 0 renders in the calling thread, which is faster for these frames
# (benchmarks/RESULTS.md, "RoverEnv speed"). Read when the GL context is first made (lazily,
# after this import); an LP_NUM_THREADS set by the user wins.
os.environ.setdefault("LP_NUM_THREADS", "0")


class CameraFrame(NamedTuple):
    """One forward-camera frame (arrays owned by the caller).

    :param rgb: uint8 (H, W, 3).
    :param depth: float32 (H, W) metric depth along the optical axis in metres (the far
        clip distance where nothing was hit), or None when not requested.
    :param pedestrian_mask: bool (H, W), True on pixels showing any pedestrian geom, or
        None when not requested.
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    pedestrian_mask: np.ndarray | None



logger = logging.getLogger(__name__)

_GL_PID: int | None = None  # the process that created this module's first GL context


def _prefer_forkserver_children() -> None:
    """Make ``forkserver`` this process's default start method, unless one was chosen.

    Once this process holds an EGL context, a child made by ``fork()`` cannot render (see
    :func:`_check_not_forked_after_gl`). Subprocess envs started afterwards with the default
    context (``gym.make_vec(id, vectorization_mode="async")`` after a ``gym.make`` that
    rendered, as in a notebook) then work. A start method set by the program
    (``multiprocessing.set_start_method``) or a context passed explicitly is left alone.
    """
    if multiprocessing.get_start_method(allow_none=True) is not None:
        return
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return
    multiprocessing.set_start_method("forkserver")
    logger.info("OpenGL started in this process: new subprocesses default to 'forkserver' "
                "(a forked child could not render)")  # fmt: skip


def _check_not_forked_after_gl() -> None:
    """Raise instead of hanging when OpenGL was started before this process was forked.

    EGL/Mesa state (driver threads, locks) does not survive ``fork()``: a child that
    renders after its parent rendered blocks forever.
    """
    if _GL_PID is not None and _GL_PID != os.getpid():
        raise RuntimeError(
            f"OpenGL rendering was started in process {_GL_PID} before it forked this one "
            f"({os.getpid()}); rendering here would hang. Start subprocess envs with the "
            "'forkserver' or 'spawn' method (gymnasium.vector.AsyncVectorEnv(..., "
            "context='forkserver'); SB3's SubprocVecEnv does by default), or render only "
            "in the worker processes."
        )


def _gl_context_class() -> type:
    """The OpenGL context for ``MUJOCO_GL`` as it is now (rover_env sets ``egl`` unless
    told otherwise), even when mujoco was imported before rover_env chose it."""
    backend = os.environ.get("MUJOCO_GL", "").lower()
    if backend == "egl":
        from mujoco.egl import GLContext
    elif backend == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        GLContext = mujoco.GLContext
    return GLContext


class GLRenderer:
    """Offscreen OpenGL rendering of a model: one context, one scene, reused buffers."""

    def __init__(self, model: mujoco.MjModel, pedestrian_geoms: np.ndarray) -> None:
        self._model = model
        width, height = model.vis.global_.offwidth, model.vis.global_.offheight
        global _GL_PID
        _check_not_forked_after_gl()
        self._gl = _gl_context_class()(width, height)
        if _GL_PID is None:
            _prefer_forkserver_children()
        _GL_PID = os.getpid()
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=model.ngeom + 64)
        self.camera_option = mujoco.MjvOption()  # groups 0-2: scenery, pedestrians, rover
        self.chase_option = mujoco.MjvOption()
        self.chase_option.geomgroup[GROUP_MARKER] = 1
        self._pedestrian_geoms = pedestrian_geoms
        self._buffers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # Reverse-Z depth buffer (1 near, 0 far) -> metres: d / (z + c).
        near = model.vis.map.znear * model.stat.extent
        far = model.vis.map.zfar * model.stat.extent
        self._depth_c = np.float32(near / (far - near))
        self._depth_d = np.float32(far * near / (far - near))

    def _bufs(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        bufs = self._buffers.get((width, height))
        if bufs is None:
            bufs = (
                np.empty((height, width, 3), dtype=np.uint8),
                np.empty((height, width), dtype=np.float32),
                np.empty((height, width, 3), dtype=np.uint8),
            )
            self._buffers[(width, height)] = bufs
        return bufs

    def render(
        self,
        data: mujoco.MjData,
        camera: mujoco.MjvCamera,
        option: mujoco.MjvOption,
        width: int,
        height: int,
        depth: bool = False,
        segmentation: bool = False,
        decorate: Callable[[mujoco.MjvScene], None] | None = None,
    ) -> CameraFrame:
        """Render ``camera``; ``decorate(scene)`` may add geoms after the scene is built."""
        model, scene, ctx = self._model, self._scene, self._ctx
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(
                f"frame {width}x{height} is larger than the offscreen buffer "
                f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}; ask for a smaller "
                "frame or build the sim with a larger camera_size"
            )
        self._gl.make_current()
        rect = mujoco.MjrRect(0, 0, width, height)
        rgb_buf, depth_buf, seg_buf = self._bufs(width, height)
        mujoco.mjv_updateScene(model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
        if decorate is not None:
            decorate(scene)
        mujoco.mjr_render(rect, scene, ctx)
        mujoco.mjr_readPixels(rgb_buf, depth_buf if depth else None, rect, ctx)
        rgb = rgb_buf[::-1].copy()
        depth_m = None
        if depth:
            depth_m = depth_buf[::-1] + self._depth_c
            np.divide(self._depth_d, depth_m, out=depth_m)
        mask = None
        if segmentation:
            mask = self._segment(rect, seg_buf)
        return CameraFrame(rgb, depth_m, mask)

    def _segment(self, rect: mujoco.MjrRect, seg_buf: np.ndarray) -> np.ndarray:
        scene = self._scene
        flags = scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_render(rect, scene, self._ctx)
            mujoco.mjr_readPixels(seg_buf, None, rect, self._ctx)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        # Segment id (1-based scene geom index, 0 = background) -> is a pedestrian geom.
        is_ped = np.zeros(scene.ngeom + 1, dtype=bool)
        geom_type = mujoco.mjtObj.mjOBJ_GEOM
        for i in range(scene.ngeom):
            g = scene.geoms[i]
            if g.segid >= 0 and g.objtype == geom_type and self._pedestrian_geoms[g.objid]:
                is_ped[g.segid + 1] = True
        seg = seg_buf[::-1].astype(np.int32)
        segid = seg[..., 0] | (seg[..., 1] << 8) | (seg[..., 2] << 16)
        np.clip(segid, 0, scene.ngeom, out=segid)
        return is_ped[segid]

    def close(self) -> None:
        if self._gl is None:
            return
        self._gl.make_current()
        self._ctx.free()
        self._gl.free()
        self._gl = None
