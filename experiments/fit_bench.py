"""Image-fitting cost: a frame, its antialiasing and its gradients, measured side by side.

Fitting poses, shapes, cameras or deformation styles to images runs ``value_and_grad`` through
:func:`jaxgfx.raster.rasterize` and :func:`jaxgfx.silhouette.analytic_antialias` thousands of
times, so what a step costs against the frame it differentiates is what a user waits for.  Every
time below is the best of ``--rounds`` interleaved rounds (each round runs every method once),
compile excluded, on one device (the process's default), all jitted:

1. The Stanford bunny (69 k triangles, from ../shared/data; an icosphere when the data is absent),
   unit size, seen by ``B`` orbit cameras (1 or 8, ``jax.vmap`` over a stacked camera for 8) at
   256x192 and 512x384:

   * ``raster_ms``: the coverage frame, ``rasterize`` with one constant channel;
   * ``antialias_ms``: the same frame and ``analytic_antialias`` of its coverage over a
     background of 0 (``antialias_x``: against ``raster_ms``);
   * ``vg_vertices_ms`` / ``vg_camera_ms``: ``value_and_grad`` of the L2 loss between that
     antialiased coverage and a target image (the mesh moved by about one pixel along the first
     camera's right axis, rendered the same way) w.r.t. the vertices / the camera;
   * the rasterizer's own reverse: ``raster_attr_ms`` is ``rasterize`` with the vertex positions
     as attributes, ``raster_rev_vertices_ms`` the ``grad`` of its summed colour w.r.t. the
     vertices and ``raster_rev_camera_ms`` the ``grad`` of its summed finite depth w.r.t. the
     camera, each ``_x`` against ``raster_attr_ms``.

2. A whole style-fit step, the README's image fit: the demo arm (:func:`jaxgfx.skin.demo_arm`,
   spline skinning with both styles), 2 poses x 2 cameras at 256x192 (and 512x384), the loss of
   :func:`jaxgfx.skin.style_image_loss` (silhouette and depth terms): its forward
   (``forward_ms``), its ``value_and_grad`` w.r.t. the style's log-parameters (``vg_ms``) and a
   whole step with Adam's update (``step_ms``), each ``_x`` against the forward.

3. Mitsuba 3 (Dr.Jit's LLVM backend, variant ``llvm_ad_rgb``, integrator ``direct_projective``:
   silhouette gradients by projective sampling; ``pip install '.[bench]'``), on the bunny at
   256x192 with one camera: a black mesh before a white constant emitter renders ``1 -
   coverage``, the same L2 loss against its own render of the moved mesh; the time of a forward
   and backward at 4 samples a pixel beside ours, and the cosine between its vertex-gradient
   field at 64 samples a pixel and ours (``gradient_cosine_64spp``).  Beside it: the cosine
   between two of its 64-sample fields at different seeds (``mitsuba_seeds_cosine``, its
   estimate's spread), the median over vertices of the cosine between the two gradient vectors
   (``median_vertex_cosine``: do both push each vertex the same way?), and the cosine after
   summing each field over cubes 3 and 8 pixels wide at the orbit radius (``cosine_3px_cells``,
   ``cosine_8px_cells``: what a parameter that moves a few pixels of outline alike sees).
   Dr.Jit needs a system LLVM >= 16 (its path in ``DRJIT_LIBLLVM_PATH``); without one, or
   without the package, the row gives the reason.  It runs in a process of its own
   (``experiments/_mitsuba_peer.py``): a failing LLVM aborts it.

    python -m experiments.fit_bench [--quick] [--out DIR] [--rounds N]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import trimesh

from experiments.common import DATA, best_rounds, machine, markdown_table, write_table
from jaxgfx import skin
from jaxgfx.camera import camera_basis, focal_lengths, look_at, orbit_cameras, stack_cameras
from jaxgfx.raster import rasterize
from jaxgfx.silhouette import silhouette_edges

BUNNY = DATA / "meshes" / "bun_zipper.ply"
RADIUS = 1.8  # orbit radius in mesh units (the mesh is unit size)
FOV = 40.0


def load_mesh(quick: bool) -> tuple[str, np.ndarray, np.ndarray]:
    """The bunny, centred and scaled to unit size (an icosphere when quick or absent)."""
    if quick or not BUNNY.exists():
        mesh = trimesh.creation.icosphere(subdivisions=3)
        name = "icosphere (3 subdivisions)"
    else:
        mesh = trimesh.load(BUNNY)
        name = "bunny"
    v = np.asarray(mesh.vertices, np.float64)
    v = (v - (v.max(0) + v.min(0)) / 2) / np.ptp(v, 0).max()
    return name, v.astype(np.float32), np.asarray(mesh.faces, np.int32)


def best_ms(methods: dict, rounds: int) -> dict:
    """Best milliseconds of each method over interleaved rounds, after one warm-up call each."""
    for fn in methods.values():  # compile and warm up
        jax.block_until_ready(fn())
    return {k: s * 1e3 for k, s in best_rounds(methods, rounds)[0].items()}


def coverage(cam, v, f, edges):
    """(H, W) antialiased coverage of one mesh from one camera, over a background of 0."""
    return skin.render_silhouette_depth(cam, v, f, edges)[0]


def one_pixel_shift(cam) -> np.ndarray:
    """(3,) about one pixel at the orbit radius along ``cam``'s right axis (the target's move)."""
    return np.asarray(camera_basis(cam)[0]) * RADIUS / float(focal_lengths(cam)[0])


# --quick compiles one function of each kind (the table's other columns stay blank): the
# style step is the reverse through skinning, the frame and its antialiasing.
QUICK_MESH = ("antialias", "raster_rev_camera")
QUICK_STYLE = ("step",)


def mesh_table(name, v, f, sizes, batches, rounds, only=None) -> list[dict]:
    """Section 1: per size and batch, the frame, its antialiasing and their gradients.

    ``only``: the methods to time (default all).
    """
    edges = jnp.asarray(silhouette_edges(f))
    v, f = jnp.asarray(v), jnp.asarray(f)
    rows = []
    for w, h in sizes:
        for batch in batches:
            cams = orbit_cameras([0, 0, 0], RADIUS, batch, fov=FOV, width=w, height=h)
            first = jax.tree_util.tree_map(lambda a: a[0], cams)
            shift = one_pixel_shift(first)  # the target: the mesh moved by about a pixel
            one = batch == 1
            cam_arg = first if one else cams

            def each(fn, cam, one=one):
                return fn(cam) if one else jax.vmap(fn)(cam)

            def image(vv, cam, each=each):
                return each(lambda c: coverage(c, vv, f, edges), cam)

            antialias = jax.jit(image)  # the target's program is the timed one
            target = antialias(v + jnp.asarray(shift), cam_arg)

            def loss(vv, cam, target=target, image=image):
                return jnp.sum((image(vv, cam) - target) ** 2)

            def raster_cov(vv, cam, each=each):
                ones = jnp.ones((vv.shape[0], 1), jnp.float32)
                return each(lambda c: rasterize(c, vv, f, ones).tri_id, cam)

            def raster_attr(vv, cam, each=each):
                return each(lambda c: rasterize(c, vv, f, vv).color, cam)

            def colour_sum(vv, cam, each=each):
                return jnp.sum(each(lambda c: rasterize(c, vv, f, vv).color, cam))

            def depth_sum(cam, vv, each=each):
                d = each(lambda c: rasterize(c, vv, f).depth, cam)
                return jnp.sum(jnp.where(jnp.isfinite(d), d, 0.0))

            fns = dict(
                raster=jax.jit(raster_cov),
                antialias=antialias,
                vg_vertices=jax.jit(jax.value_and_grad(loss)),
                vg_camera=jax.jit(jax.value_and_grad(loss, argnums=1)),
                raster_attr=jax.jit(raster_attr),
                raster_rev_vertices=jax.jit(jax.grad(colour_sum)),
                raster_rev_camera=jax.jit(jax.grad(depth_sum)),
            )
            methods = {
                k: (lambda fn=fn, c=cam_arg: fn(c, v)) if k == "raster_rev_camera" else
                (lambda fn=fn, c=cam_arg: fn(v, c))
                for k, fn in fns.items() if only is None or k in only
            }  # fmt: skip
            ms = best_ms(methods, rounds)
            row = dict(mesh=name, triangles=int(f.shape[0]), size=f"{w}x{h}", batch=batch)
            for k, base in (
                ("raster", None), ("antialias", "raster"), ("vg_vertices", "raster"),
                ("vg_camera", "raster"), ("raster_attr", None),
                ("raster_rev_vertices", "raster_attr"), ("raster_rev_camera", "raster_attr"),
            ):  # fmt: skip
                row[f"{k}_ms"] = ms.get(k)
                if base is not None:
                    both = k in ms and base in ms
                    row[f"{k}_x"] = ms[k] / ms[base] if both else None
            rows.append(row)
            print(markdown_table([row], list(row)), flush=True)
    return rows


def style_table(sizes, rounds, only=None) -> list[dict]:
    """Section 2: the README's image fit (2 poses x 2 cameras), forward, gradient and step.

    ``only``: the methods to time (default all).
    """
    arm = skin.demo_arm()
    poses = jax.vmap(lambda b: skin.demo_arm_pose(arm.rig, b, 0.3))(jnp.array([0.6, 1.2]))

    def skin_fn(style, pose):
        return skin.skin_exact(arm.rig, pose, arm.binding, style, styles="both")[0]

    faces = jnp.asarray(arm.faces, jnp.int32)
    init = skin.identity_style((16, 16), 16)
    edges = jnp.asarray(skin.welded_silhouette_edges(skin_fn, init, poses, np.asarray(arm.faces)))
    params = skin.style_to_params(init)
    hollow = jnp.asarray(init.hollow, jnp.float32)
    rows = []
    for w, h in sizes:
        cams = stack_cameras(
            [
                look_at([2.5, 1.2, 0.0], [0, 1, 0], width=w, height=h),
                look_at([0.0, 1.2, 2.5], [0, 1, 0], width=w, height=h),
            ]
        )
        targets = skin.render_style_images(
            skin_fn, skin.muscle_style(), poses, faces, cams, edges=edges
        )

        def loss(p, cams=cams, targets=targets):
            return skin.style_image_loss(p, skin_fn, poses, faces, edges, cams, targets, hollow)[0]

        opt = optax.adam(0.03)
        state = opt.init(params)

        @jax.jit
        def step(p, s, loss=loss, opt=opt):
            value, grads = jax.value_and_grad(loss)(p)
            updates, s = opt.update(grads, s, p)
            return optax.apply_updates(p, updates), s, value

        forward, vg = jax.jit(loss), jax.jit(jax.value_and_grad(loss))
        methods = dict(
            forward=lambda fn=forward: fn(params),
            vg=lambda fn=vg: fn(params),
            step=lambda fn=step, s=state: fn(params, s),
        )
        ms = best_ms({k: m for k, m in methods.items() if only is None or k in only}, rounds)
        row = dict(case="demo arm, 2 poses x 2 cameras", size=f"{w}x{h}")
        row["forward_ms"] = ms.get("forward")
        for k in ("vg", "step"):
            row[f"{k}_ms"] = ms.get(k)
            row[f"{k}_x"] = ms[k] / ms["forward"] if k in ms and "forward" in ms else None
        rows.append(row)
        print(markdown_table([row], list(row)), flush=True)
    return rows


def _llvm_reason() -> str | None:
    """Why Dr.Jit's LLVM backend cannot run here (None: it may)."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        m = re.search(r"LLVM[-.]?(\d+)", Path(path).name, re.IGNORECASE)
        if m and int(m.group(1)) < 16:
            return f"DRJIT_LIBLLVM_PATH is LLVM {m.group(1)}; Dr.Jit needs LLVM >= 16"
        return None
    found = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    versions = sorted({int(m) for m in re.findall(r"libLLVM-(\d+)", found)})
    if not versions or max(versions) < 16:
        have = ", ".join(map(str, versions)) or "none"
        return f"Dr.Jit needs a system LLVM >= 16 (DRJIT_LIBLLVM_PATH); this machine has {have}"
    return None


def mitsuba_skipped() -> str | None:
    """Why Mitsuba 3 cannot run here (None: it may)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError as err:
        return f"mitsuba not installed ({err}); pip install '.[bench]'"
    return _llvm_reason()


PEER = "Mitsuba 3 (llvm_ad_rgb, direct_projective)"


def mitsuba_row(row: dict, v, f, cam, shift, ours_ms: float, ours_grad) -> dict:
    """Section 3: Mitsuba 3 on the same mesh, camera, target and loss, in a process of its own."""
    _, up, fwd = (np.asarray(x) for x in camera_basis(cam))
    eye = np.asarray(cam.position)
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(
            inp, vertices=v, faces=f, shift=shift, eye=eye, target=eye + fwd, up=up, fov=FOV,
            width=cam.width, height=cam.height,
        )  # fmt: skip
        proc = subprocess.run(
            [sys.executable, "-m", "experiments._mitsuba_peer", str(inp), str(out)],
            capture_output=True, text=True, timeout=1800,
        )  # fmt: skip
        if proc.returncode != 0 or not out.exists():
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            return {**row, "skipped": f"Mitsuba's process failed: {tail[0][:200]}"}
        res = np.load(out)
        theirs = np.asarray(res["grad"], np.float64).reshape(-1, 3)
        again = np.asarray(res["grad_again"], np.float64).reshape(-1, 3)
    ours = np.asarray(ours_grad, np.float64).reshape(-1, 3)
    pixel = RADIUS / float(focal_lengths(cam)[1])  # a pixel's size at the orbit radius
    return {
        **row,
        "mitsuba_step_ms_4spp": float(res["step_ms"]),
        "jaxgfx_step_ms": ours_ms,
        "mitsuba_over_jaxgfx": float(res["step_ms"]) / ours_ms,
        "gradient_cosine_64spp": _cosine(ours, theirs),
        "mitsuba_seeds_cosine": _cosine(theirs, again),
        "median_vertex_cosine": _median_vertex_cosine(ours, theirs),
        "cosine_3px_cells": _cosine(*_cell_sums(v, 3 * pixel, ours, theirs)),
        "cosine_8px_cells": _cosine(*_cell_sums(v, 8 * pixel, ours, theirs)),
    }


def _cosine(a, b) -> float:
    a, b = np.ravel(a), np.ravel(b)
    return float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-30))


def _median_vertex_cosine(a, b) -> float:
    """The median over vertices where both fields are above 1/1000 of their largest of the
    cosine between their two gradient vectors (do they push each vertex the same way?)."""
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    both = (na > 1e-3 * na.max()) & (nb > 1e-3 * nb.max())
    return float(np.median(np.sum(a[both] * b[both], 1) / (na[both] * nb[both])))


def _cell_sums(vertices, cell: float, *fields):
    """Each (V, 3) field summed over the vertices in each cube of side ``cell``: what a
    parameter that moves every vertex of a cube alike sees of it."""
    _, inv = np.unique(np.floor(np.asarray(vertices) / cell), axis=0, return_inverse=True)
    inv = inv.ravel()
    out = []
    for g in fields:
        s = np.zeros((inv.max() + 1, 3))
        np.add.at(s, inv, g)
        out.append(s)
    return out


def mitsuba_section(name, v, f, quick) -> dict:
    """Our step at the peer's set-up, then the peer's row (the reason, where it cannot run)."""
    w, h = (32, 24) if quick else (256, 192)
    row = dict(peer=PEER, mesh=name, size=f"{w}x{h}")
    reason = mitsuba_skipped()
    if reason is not None:
        return {**row, "skipped": reason}
    edges = jnp.asarray(silhouette_edges(f))
    vj, fj = jnp.asarray(v), jnp.asarray(f)
    cam = jax.tree_util.tree_map(
        lambda a: a[0], orbit_cameras([0, 0, 0], RADIUS, 1, fov=FOV, width=w, height=h)
    )
    shift = one_pixel_shift(cam)
    target = jax.jit(lambda vv: coverage(cam, vv, fj, edges))(vj + jnp.asarray(shift))
    vg = jax.jit(
        jax.value_and_grad(lambda vv: jnp.sum((coverage(cam, vv, fj, edges) - target) ** 2))
    )
    ms = best_ms(dict(step=lambda: vg(vj)), 3 if quick else 7)
    return mitsuba_row(row, v, f, cam, shift, ms["step"], vg(vj)[1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--quick", action="store_true", help="32x24, a batch of 2, one round (smoke test)"
    )
    ap.add_argument("--out", default="out/fit_bench")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    args = ap.parse_args(argv)
    rounds = 1 if args.quick else args.rounds
    name, v, f = load_mesh(args.quick)
    # --quick: the batched path only (a vmap of the one-camera functions), at 32x24.
    sizes = [(32, 24)] if args.quick else [(256, 192), (512, 384)]
    batches = [2] if args.quick else [1, 8]
    print(machine(), flush=True)
    quick = args.quick
    mesh_rows = mesh_table(name, v, f, sizes, batches, rounds, QUICK_MESH if quick else None)
    style_rows = style_table(sizes, rounds, QUICK_STYLE if quick else None)
    peer = mitsuba_section(name, v, f, args.quick)
    print(markdown_table([peer], list(peer)), flush=True)
    md = "\n\n".join(
        [
            machine(),
            "## 1. Frame, antialiasing and gradients\n\n"
            + markdown_table(mesh_rows, list(mesh_rows[0])),
            "## 2. A style-fit step\n\n" + markdown_table(style_rows, list(style_rows[0])),
            "## 3. Mitsuba 3\n\n" + markdown_table([peer], list(peer)),
        ]
    )
    data = dict(machine=machine(), mesh=mesh_rows, style=style_rows, mitsuba=peer)
    write_table(args.out, "Image-fitting cost", md, json.loads(json.dumps(data, default=float)))


if __name__ == "__main__":
    main()
