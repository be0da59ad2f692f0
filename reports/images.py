"""What the page shows of the run's images: the image grid with its previews and ΔE76 heat maps
(drawn from the run's EXRs), the bias table of the biased estimators, and Lu 2013's sample
picture from the inputs the run saved (:mod:`iblbench.harness.protocol.report_inputs`)."""
from __future__ import annotations

import pathlib

import markupsafe
import numpy as np
import pandas as pd

from iblbench.harness.protocol.metrics import Scorer
from iblbench.harness.protocol.report_inputs import pool_path, read_pool_picture, shown_spp
from iblbench.harness.protocol.results import image_stem
from iblbench.harness.protocol.stats import LEVEL, interval_text, mean_ci, t_quantile
from iblbench.harness.protocol.sweep import estimator_tags
from iblbench.reports import sample_picture
from iblbench.reports.figures import slugify
from iblbench.reports.previews import HEAT_SCALE, heat_scale, write_heat_map, write_preview
from iblbench.reports.tables import intervals, table_html
from iblbench.scenes import cubemap
from iblbench.foundation.errors import InputError, argument
from iblbench.scenes.imageio import read_exr

def choose_spp(table: pd.DataFrame, scene: str, frame: int, seed: int, spp: int | None) -> dict:
    """The spp shown per estimator: ``spp`` when given, else the largest spp every estimator
    of the scene ran (at this frame and seed); an estimator without it shows its own largest."""
    rows = table[(table.scene == scene) & (table.frame == frame) & (table.seed == seed)]
    return shown_spp({name: set(g.spp) for name, g in rows.groupby("estimator", sort=False)}, spp)


def covered(mask: np.ndarray | None, reference: np.ndarray) -> np.ndarray:
    """The covered pixels: the G-buffer's ``mask`` the run saved; where it saved none (a run
    made before) or one of another size, the reference's non-black pixels (the reference is
    black outside the mask, so only black covered pixels differ)."""
    if mask is None or mask.shape != reference.shape[:2]:
        return (reference != 0.0).any(axis=-1)
    return mask


class FramePreviews:
    """The PNG previews and ΔE76 heat maps of one (scene, frame), drawn into the report from the
    run's EXRs (the run writes no PNG: they cost it ~5 ms of host time per cell, and a report
    shows one frame and seed).  A PNG no older than its EXRs (and, for a heat map, drawn on
    today's HEAT_SCALE) is kept, so a second report draws nothing.  The reference is read only
    when something must be drawn: the exposure and the heat maps are the run's scorer's
    (:class:`~iblbench.harness.protocol.metrics.Scorer`) over the G-buffer's ``mask`` the run
    saved, non-finite estimate values black as in its scoring.  :func:`covered` says what
    stands in for a mask the run did not save."""

    def __init__(self, run_images: pathlib.Path, report: pathlib.Path, where: str, mask):
        self.run_images, self.report, self.where, self._mask = run_images, report, where, mask
        self._scorer = None

    def _scorer_of_frame(self) -> Scorer:
        if self._scorer is None:
            reference = read_exr(self.run_images / "reference.exr")
            self._scorer = Scorer(reference, covered(self._mask, reference), ("de76",))
        return self._scorer

    def _target(self, name: str, sources: list[pathlib.Path], scale: str | None = None):
        """(the PNG's path relative to the report or None when a source EXR is missing, whether
        it must be drawn)."""
        try:
            newest = max(source.stat().st_mtime_ns for source in sources)
        except FileNotFoundError:
            return None, False
        relative = f"{self.where}/{name}"
        target = self.report / relative
        try:
            stale = target.stat().st_mtime_ns < newest
        except FileNotFoundError:
            target.parent.mkdir(parents=True, exist_ok=True)
            return relative, True
        return relative, stale or (scale is not None and heat_scale(target) != scale)

    def reference(self) -> str | None:
        relative, draw = self._target("reference.png", [self.run_images / "reference.exr"])
        if draw:
            scorer = self._scorer_of_frame()
            write_preview(self.report / relative, scorer.reference, scorer.k)
        return relative

    def estimate(self, stem: str) -> tuple[str | None, str | None]:
        """The preview and the heat map of the estimate ``stem``; (None, None) when its EXR is
        missing or does not read whole (the page shows "no image" there instead of failing as a
        whole: issue 23; a resumed run renders such a cell again)."""
        sources = [self.run_images / f"{stem}.exr", self.run_images / "reference.exr"]
        preview, draw_preview = self._target(f"{stem}.png", sources[:1])
        heat, draw_heat = self._target(f"{stem}_de76.png", sources, HEAT_SCALE)
        if draw_preview or draw_heat:
            scorer = self._scorer_of_frame()
            try:
                radiance = read_exr(sources[0])
            except InputError:
                return None, None
            if draw_preview:
                write_preview(self.report / preview, radiance, scorer.k)
            if draw_heat:
                radiance = np.where(np.isfinite(radiance), radiance, 0.0)
                write_heat_map(self.report / heat, scorer.delta_e_images(radiance)[0])
        return preview, heat


def image_grid(run_dir, report, table, cells, scene, frame, seed, spp, mask) -> dict:
    """The images of one scene at (``frame``, ``seed``), drawn into the report by
    :class:`FramePreviews` (``mask``: the scene's G-buffer mask, None where the run saved
    none): ``tiles``,
    the grid (the reference, each estimator at its :func:`choose_spp` spp and its ΔE76 heat map,
    captioned with the cell's mean ΔE76 over seeds and its interval), and ``viewer``, the
    compare viewer's ``choices`` (every estimate and heat map of the frame and seed, each spp)
    with the two estimators it opens on (``a``, ``b``) and the ``reference``."""
    previews = FramePreviews(pathlib.Path(run_dir) / "images" / scene / f"f{frame}",
                             pathlib.Path(report), f"images/{scene}/f{frame}", mask)
    chosen = choose_spp(table, scene, frame, seed, spp)
    rows = table[(table.scene == scene) & (table.frame == frame) & (table.seed == seed)]
    cell = cells[cells.scene == scene].set_index(["estimator", "spp"])
    reference = previews.reference()
    tiles = [{"title": "reference", "subtitle": ["exact quadrature"], "src": reference,
              "heat": None}]
    choices = [{"label": "reference (exact quadrature)", "src": reference}] if reference else []
    shown = {}
    for name, runs in rows.groupby("estimator", sort=False):
        for row in runs.sort_values("spp").to_dict("records"):
            n = int(row["spp"])
            src, heat = previews.estimate(image_stem(row))
            choices += [{"label": label, "src": image} for label, image in (
                (f"{name} @ {n} spp", src), (f"{name} @ {n} spp: ΔE76 heat map", heat)) if image]
            if n != chosen[name]:
                continue
            over_seeds = cell.loc[(name, n)]
            tiles.append({"title": name, "src": src, "heat": heat, "subtitle": [
                f"{n} spp, mean ΔE76", f"seed {seed}: {row['mean_delta_e76']:.3g}",
                f"{over_seeds.seeds} seeds: " + interval_text(
                    over_seeds.mean_delta_e76, over_seeds.mean_delta_e76_half, over_seeds.seeds)]})
            if src:
                shown[name] = src
    pair = list(shown.values())[:2]
    pair = pair if len(pair) == 2 else [reference, *pair]   # one estimator: against the reference
    viewer = {"choices": choices, "reference": reference, "a": pair[0], "b": pair[-1]}
    return {"frame": frame, "seed": seed, "tiles": tiles, "viewer": viewer,
            "spp": sorted(set(chosen.values()))}


def bias_table(run_dir, table, cells, scene, frame, mask) -> markupsafe.Markup | None:
    """The bias left at the highest spp by each estimator of the scene tagged biased
    (``tags.unbiased = False``: fis, havran, smc), from the frame's estimate EXRs of every seed
    at that spp against the reference EXR, over covered pixels (:func:`covered`): the image-mean
    bias Σ Y(x)/Σ Y(r) − 1 in luminance, mean over seeds with its 95% interval, and the relMSE
    of the bias, mean(((m − r)² − s²/n)/(r² + 0.01)) with m and s a pixel's mean and standard
    deviation over the n seeds (the squared bias with the variance of the mean taken out, so
    it estimates the floor the cell's relMSE, shown beside it, levels off at), its 95% interval
    by the jackknife over seeds (n ≥ 3).  An estimator whose EXRs are gone or do not read whole
    is left out; None when none is left."""
    folder = pathlib.Path(run_dir) / "images" / scene / f"f{frame}"
    rows = table[(table.scene == scene) & (table.frame == frame)]
    shown = []
    for label, runs in rows.groupby("estimator", sort=False):
        spp = int(runs.spp.max())
        paths = [folder / f"{image_stem(row)}.exr" for row in runs[runs.spp == spp].to_dict("records")]
        tags = estimator_tags(label)   # None: an estimator this installation lacks
        biased = tags is not None and not tags.unbiased
        if not biased or not all(p.exists() for p in [folder / "reference.exr", *paths]):
            continue
        n = len(paths)
        try:
            reference = read_exr(folder / "reference.exr")
            inside = covered(mask, reference)
            reference = reference[inside].astype(np.float64)
            estimates = np.array([read_exr(path)[inside] for path in paths], np.float64)
        except InputError:      # an EXR that no longer reads whole: left out, as one gone
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            image_mean = mean_ci(cubemap.luminance(estimates).sum(1) / cubemap.luminance(reference).sum() - 1)

        def bias_rel_mse(seeds):
            squared_bias = (seeds.mean(0) - reference) ** 2 - seeds.var(0, ddof=1) / len(seeds)
            return float(np.mean(squared_bias / (reference ** 2 + 0.01)))

        bias = bias_rel_mse(estimates) if n > 1 else np.nan
        left_out = np.array([bias_rel_mse(np.delete(estimates, i, 0)) for i in range(n)]) if n > 2 else np.nan
        bias_half = t_quantile(n - 1, LEVEL) * np.sqrt((n - 1) * np.mean((left_out - left_out.mean()) ** 2)) \
            if n > 2 else np.nan
        cell = cells[(cells.scene == scene) & (cells.estimator == label) & (cells.spp == spp)]
        shown.append({"estimator": label, "spp": spp, "seeds": n, "image-mean bias (%)": interval_text(
                          100 * image_mean.mean, 100 * (image_mean.high - image_mean.mean), n),
                      "relMSE of the bias": interval_text(bias, bias_half, n),
                      "relMSE": intervals(cell, "rel_mse")[0]})
    return table_html(pd.DataFrame(shown), "summary") if shown else None


def default_pixel(mask: np.ndarray) -> tuple[int, int]:
    """The covered pixel (x, y) nearest the image centre."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    i = np.argmin((xs + 0.5 - w / 2) ** 2 + (ys + 0.5 - h / 2) ** 2)
    return int(xs[i]), int(ys[i])


def picture_section(draw, run_dir, surface, scene: str, frame: int, spp: int | None,
                   pixel: tuple[int, int] | None) -> dict:
    """Draw (by ``draw``, :meth:`Figures.draw`) the sample picture of ``scene`` from the pool
    and splits the run saved for ``frame`` (:mod:`iblbench.harness.protocol.report_inputs`) and
    the scene's saved normals and mask (``surface``, None where the run saved none); a dict
    for the template (``error`` says why there is none)."""
    if surface is None:
        return {"error": "the run folder holds no inputs for it (a run made before runs saved "
                         "them: run again into a new folder to have it)"}
    saved = read_pool_picture(run_dir, scene, frame)
    if saved is None:
        return {"error": "no estimator of this scene reads Lu 2013's light-sample pool with the "
                         "shared sequence (uniform, balanced, balanced_mis)"}
    normals, mask = surface
    x, y = default_pixel(mask) if pixel is None else pixel
    h, w = mask.shape
    if not (0 <= x < w and 0 <= y < h) or not mask[y, x]:
        raise InputError(None, f"{argument('pixel', (x, y))} is not a covered pixel of {scene} "
                               f"({w}×{h})")
    if spp is not None and spp != saved.spp:
        return {"error": f"the run saved the pool at {saved.spp} spp only (report --spp {spp})"}
    normal = normals[y, x].astype(np.float64)
    unit = normal / np.linalg.norm(normal)
    selections = sample_picture.pool_selections(saved, (x, y), unit)
    frames = sample_picture.cross_frames(normal)
    background = sample_picture.cross_image(saved.env, unit, frames)
    panels = []
    for sel in selections:
        relative = f"sample_picture_{slugify(scene)}_{slugify(sel.estimator)}.png"
        draw(relative, sample_picture.plot_sample_picture, saved.env, normal, sel, background)
        panels.append(relative)
    return {"panels": panels, "notes": [f"{name}: each pixel reads the pool from its own hashed "
                                        "offset (interleaved), not shown"
                                        for name in saved.interleaved],
            "pixel": (x, y), "normal": normal, "spp": saved.spp,
            "source": f"saved by the run ({scene}/{pool_path(run_dir, scene, frame).name})",
            "selections": [{"estimator": s.estimator, **s.counts,
                            "n_f": ", ".join(f"{v:.2f}" for v in s.n_f),
                            "per_face": ", ".join(str(int(v)) for v in s.selected_per_face),
                            "brdf": s.ticks[6] / s.ticks_per_sample} for s in selections],
            "data": selections}


__all__ = ["choose_spp", "covered", "FramePreviews", "image_grid", "bias_table", "default_pixel",
           "picture_section"]
