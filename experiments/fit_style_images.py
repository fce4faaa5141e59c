"""Fitting deformation styles to depth and silhouette images (thesis 5.6 seen through cameras).

A hidden style (smooth random textures and curves) deforms a character; we render its depth and
antialiased silhouette images (4 poses x 2 cameras, 256x192) and fit a style to those images
alone, starting from the neutral (identity) style: the loss :func:`jaxgfx.skin.fit_style_images`
minimizes (:func:`jaxgfx.skin.style_image_loss`), with its optimizer (Adam, peak learning rate
0.03, cosine decay to 1 %) and with plain gradient descent (SGD, no momentum, the same decay),
whose steps are the gradient times a fixed rate, so they are only right if the gradient's size
is.  The fit never sees the target vertices; they are only used to score it, every ``--every``
steps (the curves in the JSON and the figure):

(a) the demo limb (:func:`jaxgfx.skin.demo_arm`, radius 0.22, one spline): mean / max vertex error
    in % of the limb radius before and after.  Target: mean <= 0.5 % within 500 steps (Adam).
(b) the glTF Fox's tail spline (:func:`jaxgfx.skin.gltf_spline_chain`, 4 times in its clip):
    error over the tail's vertices in % of the tail's mean radius (skipped without the data).

Each case also scores 2 held-out poses the fit never saw (``held_out_*`` columns): does the
recovered style generalize to other poses, or only reproduce the fitted images?

Figure: target vs fitted silhouettes and depth (and their difference), the loss curves, and the
vertex error against steps for each optimizer.

    python -m experiments.fit_style_images --quick --out out/fit_style_images
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from experiments.common import DATA, machine, markdown_table, write_table
from jaxgfx import skin
from jaxgfx.camera import look_at, stack_cameras

LIMB_RADIUS = 0.22  # demo_arm's radius at its root
FOX = DATA / "rigs" / "fox.glb"
CREDIT = (
    "Fox: model by PixelMannen (CC0), rigging and animation by @tomkranis (CC-BY 4.0), glTF "
    "conversion by @AsoboStudio and @scurest."
)


def smooth_random(key, shape, amp):
    """Smooth positive random field 1 + amp * (bilinear upsampled 4x4 noise)."""
    coarse = jax.random.uniform(key, shape[:-2] + (4, 4), minval=-1, maxval=1)
    return 1.0 + amp * jax.image.resize(coarse, shape, "linear")


def hidden_style(key, tex_shape=(8, 12), curve_len=12):
    """The ground truth the fit must recover (as in experiments/fit_style.py)."""
    k1, k2 = jax.random.split(key)
    return skin.make_style(
        np.asarray(smooth_random(k1, (3, *tex_shape), 0.25)),
        np.asarray(smooth_random(k2, (3, curve_len), 0.2)),
    )


def two_cameras(center, distance, width, height, fov, direction):
    """Two cameras on opposite sides of ``center`` (one along ``direction``, one mirrored)."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    back = d * np.array([-1.0, 1.0, -1.0])  # the other side, same height
    c = np.asarray(center, np.float64)
    return stack_cameras(
        [look_at(c + distance * e, c, fov, width, height, near=0.05 * distance) for e in (d, back)]
    )


def limb_problem(width, height, quick=False):
    """Demo arm, 4 poses (bends 0.4-2.2 rad, twists +-0.6-1.2 rad), 2 cameras; 2 held out."""
    arm = skin.demo_arm()
    bends = jnp.array([0.4, 1.0, 1.6, 2.2])
    twists = jnp.array([0.9, -0.6, 1.2, -1.0])
    posed = jax.vmap(lambda b, t: skin.demo_arm_pose(arm.rig, b, t))
    # quick: two small compiled programs in place of the eager ops of two batches (compiles)
    posed = jax.jit(posed) if quick else posed
    poses = posed(bends, twists)
    held_out = posed(jnp.array([0.7, 1.9]), jnp.array([-0.3, 0.8]))
    cams = two_cameras([0.0, 1.0, -0.4], 3.6, width, height, 40.0, [1.0, 0.3, 0.5])

    def skin_fn(style, pose):
        return skin.skin_exact(arm.rig, pose, arm.binding, style, styles="both")[0]

    return skin_fn, poses, arm.faces, cams, LIMB_RADIUS, None, held_out


def fox_problem(width, height):
    """The Fox with its tail one spline, at the 4 times of its clip where the tail bends most
    (the style acts in proportion to the bend; the tail's twist is 0), 2 cameras on the tail."""
    fox = skin.load_gltf_skin(str(FOX))
    chain = skin.gltf_spline_chain(fox, skin.TAIL_JOINTS, stiffness=3.0)
    grid = np.linspace(0.0, fox.duration, 64, endpoint=False)
    bends = [float(skin.bend_angle(skin.gltf_pose(fox, chain, float(t)).points)) for t in grid]
    times: list[float] = []
    for i in np.argsort(bends)[::-1]:  # largest bends first, at least 1 s apart
        if all(abs(grid[i] - t) >= 1.0 for t in times):
            times.append(float(grid[i]))
        if len(times) == 4:
            break
    times = sorted(times)
    poses = jax.tree_util.tree_map(
        lambda *x: jnp.stack(x), *[skin.gltf_pose(fox, chain, t) for t in times]
    )
    # held out: halfway between the first two and the last two fitted times
    held_out = jax.tree_util.tree_map(
        lambda *x: jnp.stack(x),
        *[skin.gltf_pose(fox, chain, 0.5 * (a + b)) for a, b in (times[:2], times[2:])],
    )

    def skin_fn(style, pose):
        return skin.skin_gltf_chain(chain, pose, style)[0]

    on_tail = np.asarray(chain.chain_vertex)
    posed = np.asarray(jax.jit(jax.vmap(lambda p: skin_fn(None, p)))(poses))[:, on_tail]
    center = posed.reshape(-1, 3).mean(0)
    size = float(np.linalg.norm(posed.reshape(-1, 3).max(0) - posed.reshape(-1, 3).min(0)))
    cams = two_cameras(center, 1.6 * size, width, height, 40.0, [1.0, 0.5, -0.3])
    # the tail's mean cross-section radius about its spline (the binding's local offsets)
    radius = float(np.mean(np.linalg.norm(np.asarray(chain.binding.local)[:, 0, :2], axis=1)))
    return skin_fn, poses, fox.faces, cams, radius, on_tail, held_out


def vertex_errors(skin_fn, poses, held_out, radius, subset):
    """``errors(style, truth)``: mean and max vertex distance in % of ``radius`` over the fitted
    poses, then the same over the held-out poses (one compile: both sets in one batch)."""
    run = jax.jit(jax.vmap(skin_fn, in_axes=(None, 0)))
    both = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), poses, held_out)
    n_fit = jax.tree_util.tree_leaves(poses)[0].shape[0]

    def errors(style, truth):
        d = np.linalg.norm(np.asarray(run(style, both)) - np.asarray(run(truth, both)), axis=-1)
        if subset is not None:
            d = d[:, subset]
        d = d / radius * 100
        fit, held = d[:n_fit], d[n_fit:]
        return float(fit.mean()), float(fit.max()), float(held.mean()), float(held.max())

    return errors


def make_optimizer(name, lr, steps):
    """``adam``: :func:`jaxgfx.skin.fit_style_images`' default; ``sgd``: plain gradient descent
    (no momentum) with the same cosine decay."""
    schedule = optax.cosine_decay_schedule(lr, max(steps, 1), alpha=0.01)
    return optax.adam(schedule) if name == "adam" else optax.sgd(schedule)


def fit_curve(problem, targets, init, optimizer, args, weights, edges, score):
    """:func:`jaxgfx.skin.fit_style_images` with ``optimizer``, scoring the style every
    ``args.every`` steps; returns the fit and the curve [(step, *score)]."""
    skin_fn, poses, faces, cams, *_ = problem
    curve = [(0, *score(init))]

    def every(i, loss, params):
        if (i + 1) % args.every == 0 or i + 1 == args.steps:
            curve.append((i + 1, *score(skin.params_to_style(params, init.hollow))))

    fit = skin.fit_style_images(
        skin_fn, poses, faces, cams, targets, init, steps=args.steps,
        silhouette_weight=weights[0], depth_weight=weights[1], depth_clip=args.depth_clip,
        optimizer=optimizer, progress=False, callback=every, edges=edges,
    )  # fmt: skip
    return fit, curve


def run_case(name, problem, truth, init, args, weights):
    skin_fn, poses, faces, cams, radius, subset, held_out = problem
    edges = jnp.asarray(skin.welded_silhouette_edges(skin_fn, init, poses, faces))
    render = jax.jit(
        lambda s: skin.render_style_images(skin_fn, s, poses, faces, cams, edges=edges)
    )
    targets = render(truth)
    errors = vertex_errors(skin_fn, poses, held_out, radius, subset)
    before = errors(init, truth)
    rows, results = [], []
    for opt in args.optimizers:
        lr = args.lr if opt == "adam" else args.sgd_lr
        t0 = time.perf_counter()
        fit, curve = fit_curve(
            problem, targets, init, make_optimizer(opt, lr, args.steps), args, weights, edges,
            lambda s: errors(s, truth),
        )  # fmt: skip
        style, losses = fit.style, fit.loss_history
        seconds = time.perf_counter() - t0
        after = curve[-1][1:]
        rows.append(
            {
                "case": name,
                "optimizer": f"{opt} {lr:g}",
                "faces": int(np.shape(faces)[0]),
                "images": f"{targets.depth.shape[0]}x{targets.depth.shape[1]} "
                f"{targets.depth.shape[3]}x{targets.depth.shape[2]}",
                "mean_before_%": before[0],
                "mean_after_%": after[0],
                "max_after_%": after[1],
                "held_out_mean_before_%": before[2],
                "held_out_mean_after_%": after[2],
                "held_out_max_after_%": after[3],
                "steps": args.steps,
                "seconds": seconds,
                "loss_before": float(losses[0]),
                "loss_after": float(losses[-1]),
            }
        )
        results.append((f"{name}, {opt}", losses, curve, (targets, render(init), render(style))))
        print(rows[-1], flush=True)
    return rows, results


def plot(path, results):
    """Per case and optimizer, two (pose, camera) views cropped to the character: target
    silhouette and depth, depth error of the neutral and of the fitted style, silhouette error
    of the fitted style; the loss curve and the mean vertex error (fitted and held-out poses)
    against steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxgfx.io import atomic_write

    views = ((0, 0), (3, 1))
    fig, axes = plt.subplots(
        2 * len(results), 6, figsize=(18, 2.9 * 2 * len(results)), squeeze=False
    )
    for c, (name, losses, curve, (target, initial, fitted)) in enumerate(results):
        for r, (p, k) in enumerate(views):
            ax = axes[2 * c + r]
            td = np.asarray(target.depth[p, k])
            finite = np.isfinite(td)
            ys, xs = np.nonzero(finite | (np.asarray(target.silhouette[p, k]) > 0))
            m = 4  # pixels of margin around the character
            crop = np.s_[
                max(ys.min() - m, 0) : ys.max() + m + 1, max(xs.min() - m, 0) : xs.max() + m + 1
            ]
            lo, hi = td[finite].min(), td[finite].max()

            e0, e1 = (
                np.where(finite & np.isfinite(d), d - np.where(finite, td, 0.0), np.nan)
                for d in (np.asarray(initial.depth[p, k]), np.asarray(fitted.depth[p, k]))
            )
            s0 = float(np.nanmax(np.abs(e0))) or 1.0
            s1 = float(np.nanpercentile(np.abs(e1), 99)) or 1.0
            panels = [
                (np.asarray(target.silhouette[p, k]), "gray", 0, 1, "target silhouette"),
                (np.where(finite, td, np.nan), "viridis_r", lo, hi, "target depth"),
                (e0, "RdBu", -s0, s0, f"depth err., neutral (+-{s0:.2g})"),
                (e1, "RdBu", -s1, s1, f"depth err., fitted (+-{s1:.2g})"),
                (
                    np.asarray(fitted.silhouette[p, k] - target.silhouette[p, k]),
                    "RdBu", -0.5, 0.5, "silhouette err., fitted (+-0.5)",
                ),
            ]  # fmt: skip
            for a, (img, cmap, vmin, vmax, title) in zip(ax[:5], panels, strict=True):
                a.imshow(img[crop], cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
                a.set_title(f"{name} pose {p} cam {k}\n{title}", fontsize=8)
                a.axis("off")
            if r == 0:
                ax[5].semilogy(losses, label="total")
                ax[5].set_xlabel("step")
                ax[5].set_ylabel("image loss")
                ax[5].set_title(f"{name}: loss", fontsize=9)
            else:
                steps, fit_err, held_err = (np.asarray([c[i] for c in curve]) for i in (0, 1, 3))
                ax[5].semilogy(steps, fit_err, ".-", label="fitted poses")
                ax[5].semilogy(steps, held_err, ".-", label="held-out poses")
                ax[5].set_xlabel("step")
                ax[5].set_ylabel("mean vertex error, %")
                ax[5].legend(fontsize=7)
                ax[5].set_title(f"{name}: vertex error", fontsize=9)
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="the limb only, 64x48 images, 3 steps (smoke test)"
    )
    ap.add_argument("--out", default=None, help="folder for the table (.md/.json) and figure")
    ap.add_argument("--steps", type=int, default=None, help="optimization steps (default 500)")
    ap.add_argument("--size", default=None, help="image size WxH (default 256x192)")
    ap.add_argument("--lr", type=float, default=0.03, help="Adam's peak learning rate")
    ap.add_argument("--sgd-lr", type=float, default=0.2, help="SGD's peak learning rate")
    ap.add_argument(
        "--optimizers",
        default=None,
        help="comma-separated: adam (the library's optimizer), sgd (default both; --quick adam)",
    )
    ap.add_argument("--every", type=int, default=25, help="score the style every this many steps")
    ap.add_argument("--weights", default="1,1", help="silhouette,depth loss weights")
    ap.add_argument(
        "--depth-clip", type=float, default=4.0,
        help="leave pixels with a depth residual over this many pixels out of the depth term",
    )  # fmt: skip
    ap.add_argument(
        "--cases", default=None, help="fits to run, comma-separated: limb,fox (--quick: limb)"
    )
    args = ap.parse_args(argv)
    # quick: 3 steps run every part of the fit loop (its compile is most of a fit's time)
    args.steps = args.steps or (3 if args.quick else 500)
    optimizers = args.optimizers or ("adam" if args.quick else "adam,sgd")
    args.optimizers = [o.strip() for o in optimizers.split(",") if o.strip()]
    if not args.optimizers or set(args.optimizers) - {"adam", "sgd"}:
        ap.error(f"--optimizers: choose from adam, sgd, got {args.optimizers!r}")
    w, h = map(int, (args.size or ("64x48" if args.quick else "256x192")).split("x"))
    weights = tuple(float(x) for x in args.weights.split(","))
    print(machine())
    truth = hidden_style(jax.random.key(0))
    init = skin.identity_style((8, 12), 12)
    chosen = args.cases or ("limb" if args.quick else "limb,fox")
    cases = [c.strip() for c in chosen.split(",") if c.strip()]
    if not cases or set(cases) - {"limb", "fox"}:
        ap.error(f"--cases: choose from limb, fox (comma-separated), got {chosen!r}")
    if args.quick and args.cases is None:
        print("(b) fox tail skipped in --quick (a second compile; run without --quick for it)")
    rows, results = [], []
    for case in cases:
        if case == "fox" and not FOX.exists():
            print(f"(b) fox tail skipped: {FOX} is absent (the glTF sample Fox)")
            continue
        if case == "limb":
            name, problem = "(a) limb", limb_problem(w, h, quick=args.quick)
        else:
            name, problem = "(b) fox tail", fox_problem(w, h)
        case_rows, case_results = run_case(name, problem, truth, init, args, weights)
        rows += case_rows
        results += case_results
    if not rows:
        print("nothing was fitted")
        return 0
    md = markdown_table(rows, list(rows[0]))
    curves = markdown_table(
        [
            {"fit": name, "step": c[0], "mean_%": c[1], "held_out_mean_%": c[3]}
            for name, _, curve, _ in results
            for c in curve
            if c[0] % 100 == 0 or c[0] in (25, 50)
        ],
        ["fit", "step", "mean_%", "held_out_mean_%"],
    )
    limb = next((r for r in rows if r["case"] == "(a) limb" and "adam" in r["optimizer"]), None)
    verdict = (
        "not run"
        if limb is None
        else f"not judged (--quick: {w}x{h} images, {args.steps} steps)"
        if args.quick
        else ("met" if limb["mean_after_%"] <= 0.5 and limb["steps"] <= 500 else "NOT met")
    )
    footer = (
        f"\n\nVertex errors in % of the limb radius ({LIMB_RADIUS}) for (a) and of the tail's "
        "mean cross-section radius for (b), over the tail's vertices; the fits saw only the "
        f"images (4 poses x 2 cameras); held_out_*: the same errors on 2 other poses the fit never "
        f"saw. Loss: silhouette L2 (weight {weights[0]:g}) + depth L2 in "
        f"pixels at the target's depth (weight {weights[1]:g}) where both images cover, pixels "
        f"with a depth residual over {args.depth_clip:g} px left out (another surface); adam: "
        "fit_style_images' optimizer; sgd: plain gradient descent; both with the peak learning "
        "rate shown and cosine decay to 1 %; start: the neutral (identity) style; hidden style: "
        "smooth random textures (3, 8, 12) +-25 % and curves (3, 12) +-20 %; seconds include "
        "compilation.\n"
        f"Target (a), adam: mean <= 0.5 % in <= 500 steps: {verdict}.\n"
        f"{CREDIT}\nmachine: {machine()}"
    )
    text = md + "\n\nMean vertex error against steps:\n\n" + curves + footer
    print(text)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        write_table(
            args.out,
            "Fitting styles to images",
            text,
            {
                "rows": rows,
                "weights": weights,
                "depth_clip": args.depth_clip,
                "learning_rate": {"adam": args.lr, "sgd": args.sgd_lr},
                "loss": {r[0]: r[1].tolist() for r in results},
                "vertex_error_curve": {
                    r[0]: [
                        dict(zip(("step", "mean", "max", "held_mean", "held_max"), c)) for c in r[2]
                    ]
                    for r in results
                },  # fmt: skip
            },
        )
        plot(os.path.join(args.out, "fit_style_images.png"), results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
