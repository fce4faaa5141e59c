"""Mitsuba 3's side of ``experiments.fit_bench`` (section 3), run in a process of its own.

``python -m experiments._mitsuba_peer IN.npz OUT.npz``: IN holds the mesh (``vertices``,
``faces``), the camera (``eye``, ``target``, ``up``, vertical ``fov`` in degrees, ``width``,
``height``) and the target's ``shift``.  A black diffuse mesh before a white constant emitter
renders ``1 - coverage`` (``direct_projective``: silhouette gradients by projective sampling), so
the loss ``sum((coverage - target)^2)`` is the same L2 of coverage images as ours; the target is
Mitsuba's own render of the shifted mesh at 256 samples a pixel.  OUT gets ``step_ms`` (the best
of 7 forward + backward passes at 4 samples a pixel, after a warm-up: Dr.Jit compiles on the
first call), ``grad`` (V, 3), the vertex gradient at 64 samples a pixel, and ``grad_again``,
the same at another seed (the estimate's own spread).
"""

from __future__ import annotations

import sys
import time

import numpy as np


def main(inp: str, out: str) -> None:
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    d = np.load(inp)
    w, h = int(d["width"]), int(d["height"])

    def scene_for(vertices):
        mesh = mi.Mesh("mesh", len(vertices), len(d["faces"]), has_vertex_normals=False)
        params = mi.traverse(mesh)
        params["vertex_positions"] = dr.ravel(mi.Point3f(*np.asarray(vertices, np.float32).T))
        params["faces"] = dr.ravel(mi.Vector3u(*np.asarray(d["faces"], np.uint32).T))
        params.update()
        mesh.set_bsdf(mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 0}}))
        return mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "direct_projective", "sppi": 0},
                "sensor": {
                    "type": "perspective",
                    "fov": float(d["fov"]),
                    "fov_axis": "y",
                    "to_world": mi.ScalarTransform4f().look_at(
                        origin=d["eye"].tolist(), target=d["target"].tolist(), up=d["up"].tolist()
                    ),
                    "film": {
                        "type": "hdrfilm",
                        "width": w,
                        "height": h,
                        "pixel_format": "luminance",
                        "rfilter": {"type": "box"},
                    },
                },
                "emitter": {"type": "constant"},
                "mesh": mesh,
            }
        )

    target_scene = scene_for(d["vertices"] + d["shift"])
    target = 1.0 - mi.render(target_scene, spp=256)
    scene = scene_for(d["vertices"])
    params = mi.traverse(scene)
    key = "mesh.vertex_positions"
    dr.enable_grad(params[key])
    params.update()

    def step(spp: int, seed: int = 0):
        img = mi.render(scene, params, spp=spp, seed=seed)
        loss = dr.sum((1.0 - img - target) ** 2, axis=None)
        dr.backward(loss)
        g = dr.grad(params[key])
        dr.eval(g)
        dr.set_grad(params[key], 0)
        return g

    step(4)  # Dr.Jit compiles its kernels on the first call
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        step(4)
        times.append(time.perf_counter() - t0)
    grad = np.asarray(step(64)).reshape(-1, 3)
    again = np.asarray(step(64, seed=1)).reshape(-1, 3)
    np.savez(out, step_ms=min(times) * 1e3, grad=grad, grad_again=again)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
