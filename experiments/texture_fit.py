"""A photometric fit: a texture recovered from rendered images by gradient.

A cube whose six faces share one texture (each face maps the whole image) is rendered from
several cameras with :func:`jaxgfx.raster.texture` (trilinear, mip-mapped).  Starting from a
flat grey texture, Adam fits the base image to the target renders through the mip pyramid,
the lookups and the rasterizer's UV interpolation (an L2 loss on the colours).  The table
gives the image error before and after, the texture's error on the texels the views see,
and the time of one forward frame batch and one ``value_and_grad`` step; ``texture_fit.png``
shows the target texture, the fitted one (unseen texels black) and the first view of each.

The texture is the thesis author's terrain grass (``../shared/data/terrain/hvox/grass.png``,
MIT), cut to 64 x 64, or a procedural pattern without the data.

Usage::

    python -m experiments.texture_fit --out out/texture_fit
    python -m experiments.texture_fit --quick --out out/texture_fit
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from experiments.common import DATA, best_of, machine, markdown_table, write_table
from jaxgfx.camera import orbit_cameras
from jaxgfx.io import save_png
from jaxgfx.raster import mip_pyramid, rasterize, texture, uv_footprint

__all__ = ["textured_cube", "target_texture", "render_textured"]


def textured_cube():
    """``(vertices (24, 3), faces (12, 3), uvs (24, 2))``: each face maps the whole image."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    verts, faces, uvs = [], [], []
    for axis in range(3):
        for side in (-1.0, 1.0):
            a, b = [k for k in range(3) if k != axis]
            quad = np.zeros((4, 3), np.float32)
            quad[:, axis] = side
            quad[:, a] = (corners[:, 0] * 2 - 1) * side
            quad[:, b] = 1 - corners[:, 1] * 2
            base = len(verts) * 4
            verts.append(quad)
            uvs.append(corners)
            faces.append(np.array([[0, 1, 2], [0, 2, 3]]) + base)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int32), np.concatenate(uvs)


def target_texture(size: int) -> np.ndarray:
    """(size, size, 3) float32: the hvox grass texture's corner, or a procedural pattern."""
    path = DATA / "terrain" / "hvox" / "grass.png"
    if path.is_file():
        import imageio.v3 as iio

        img = np.asarray(iio.imread(path))[..., :3].astype(np.float32) / 255.0
        step = max(1, img.shape[0] // size)
        return np.ascontiguousarray(img[: size * step : step, : size * step : step])
    y, x = np.mgrid[0:size, 0:size] / size
    return np.stack(
        [0.5 + 0.4 * np.sin(9 * x), 0.5 + 0.4 * np.cos(7 * y + 2 * x), 0.3 + 0.3 * (x > y)], -1
    ).astype(np.float32)


def render_textured(cams, verts, faces, uvs, base):
    """(C, H, W, 3) colours of the textured mesh for a batch of cameras."""
    tex = mip_pyramid(base)

    def one(cam):
        out = rasterize(cam, verts, faces, uvs)
        rgb = texture(tex, out.color, uv_footprint(out.color, out.tri_id))
        return jnp.where(out.tri_id[..., None] >= 0, rgb, 0.0)

    return jax.vmap(one)(cams)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="a 16 x 16 texture, 32 x 24 views, 3 steps"
    )
    ap.add_argument("--out", default="out/texture_fit", help="folder for the table")
    args = ap.parse_args(argv)
    # quick: 3 steps run every part of the fit loop (compiling it is most of its time)
    size, (w, h), steps, n_cams = (16, (32, 24), 3, 4) if args.quick else (64, (128, 96), 300, 8)
    verts, faces, uvs = textured_cube()
    cams = orbit_cameras([0, 0, 0], 4.5, n_cams, elevation=30.0, fov=45.0, width=w, height=h)
    truth = jnp.asarray(target_texture(size))
    forward = jax.jit(lambda b: render_textured(cams, verts, faces, uvs, b))
    # quick: the targets, losses and seen texels come from the two jitted programs (forward
    # and step) in place of eager renders and an eager gradient, each a set of compiles
    targets = forward(truth) if args.quick else render_textured(cams, verts, faces, uvs, truth)

    def loss(base):
        return jnp.mean((render_textured(cams, verts, faces, uvs, base) - targets) ** 2)

    step_fn = jax.jit(jax.value_and_grad(loss))
    base = jnp.full((size, size, 3), 0.5, jnp.float32)
    t0 = time.perf_counter()
    first = jax.block_until_ready(step_fn(base))
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(forward(base))
    opt = optax.adam(0.05)
    state = opt.init(base)

    def update(g, state, base):
        upd, state = opt.update(g, state)
        return jnp.clip(optax.apply_updates(base, upd), 0.0, 1.0), state

    if args.quick:  # one compiled update in place of its eager ops
        update = jax.jit(update)
    start = float(first[0]) if args.quick else float(loss(base))
    for _ in range(steps):
        _, g = step_fn(base)
        base, state = update(g, state, base)
    # the texels the views see: those whose gradient was ever non-zero (quick: the first
    # step's gradient, taken at the same flat grey texture)
    grey_grad = first[1] if args.quick else jax.grad(loss)(jnp.full_like(base, 0.5))
    seen = np.asarray(jnp.abs(grey_grad).sum(-1) > 0)
    err = np.abs(np.asarray(base) - np.asarray(truth)).max(-1)
    end = float(step_fn(base)[0]) if args.quick else float(loss(base))
    row = dict(
        texture=f"{size}x{size}",
        views=f"{n_cams} x {w}x{h}",
        steps=steps,
        image_rmse_start=float(f"{start**0.5:.3g}"),
        image_rmse_end=float(f"{end**0.5:.3g}"),
        seen_texels_pct=round(100 * float(seen.mean()), 1),
        texel_err_median=float(f"{np.median(err[seen]):.3g}"),
        texel_err_max=float(f"{err[seen].max():.3g}"),
        forward_ms=round(1e3 * best_of(lambda: forward(base)), 2),
        value_and_grad_ms=round(1e3 * best_of(lambda: step_fn(base)), 2),
        compile_s=round(compile_s, 1),
    )
    row["grad_over_forward"] = round(row["value_and_grad_ms"] / row["forward_ms"], 2)
    # target, fitted and unseen texels (black), and the first view of each, side by side
    shown = np.where(seen[..., None], np.asarray(base), 0.0)
    views = [np.asarray(targets[0]), np.asarray(forward(base)[0])]
    scale = max(1, h // size)
    tiles = [np.kron(a, np.ones((scale, scale, 1))) for a in (np.asarray(truth), shown)]
    pad = lambda a: np.pad(a, ((0, max(0, h - a.shape[0])), (0, 4), (0, 0)))  # noqa: E731
    sheet = np.concatenate([pad(a[:h]) for a in tiles + views], axis=1)
    save_png(f"{args.out}/texture_fit.png", np.clip(sheet, 0, 1))
    title = "texture_fit: a texture recovered from images by gradient"
    text = f"machine: {machine()}\n\n" + markdown_table([row], list(row))
    print(f"# {title}\n\n{text}")
    write_table(args.out, title, text, dict(machine=machine(), rows=[row]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
