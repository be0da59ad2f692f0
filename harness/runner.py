"""``iblbench run``: scenes × estimators × spp × seeds → results table, manifest and images.

The runner skips what a scene does not need (DESIGN §2): the G-buffer is traced once per scene,
a frame cache builds only the products the chosen estimators require, and a cached reference is
never recomputed.  Every skipped stage is recorded in the manifest.
"""
from __future__ import annotations

import dataclasses
import datetime
import os
import pathlib
import platform
import subprocess
import sys
import time
from importlib.metadata import PackageNotFoundError, version

import numpy as np
from tqdm import tqdm

from iblbench.estimators.registry import get_estimator_class
from iblbench.harness.device import get_compute
from iblbench.harness.device_gbuffer import DeviceGBuffer
from iblbench.harness.framecache import PRODUCTS, FrameCache
from iblbench.harness.metrics import PROTOCOL, exposure, score
from iblbench.harness.reference import Reference
from iblbench.harness.results import cell_key, read_results, write_manifest, write_results
from iblbench.reports.previews import write_heat_map, write_preview
from iblbench.scenes.atomic import atomic_path
from iblbench.scenes.errors import InputError
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.imageio import write_exr
from iblbench.scenes.registry import load_scene

DEFAULT_SCENES = ("sphere-sun",)
DEFAULT_ESTIMATORS = ("uniform",)
DEFAULT_SPP = (16, 64, 256)
DEFAULT_SEEDS = 2
WARMUP_SEED = 0xFFFFFFFF   # a seed no benchmark cell uses


@dataclasses.dataclass
class RunConfig:
    out: pathlib.Path
    scenes: tuple[str, ...] = DEFAULT_SCENES
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    spp: tuple[int, ...] = DEFAULT_SPP
    seeds: int = DEFAULT_SEEDS
    resolution: tuple[int, int] | None = None
    device: str | None = None
    save_inputs: bool = False
    sanitize: bool = False
    env_res: int | None = None
    progress: bool | None = None   # None: a bar only on a TTY


def _package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


def _git_revision() -> str:
    """The source checkout's revision, "-dirty" with uncommitted changes; "unknown" when the
    package is not running from its own checkout (a site-packages install)."""
    package_root = pathlib.Path(__file__).resolve().parent.parent
    try:
        top = subprocess.run(["git", "-C", str(package_root), "rev-parse", "--show-toplevel"],
                             capture_output=True, text=True, check=True, timeout=10).stdout.strip()
        if pathlib.Path(top).resolve() != package_root:
            return "unknown"
        return subprocess.run(["git", "-C", top, "describe", "--always", "--dirty", "--abbrev=40"],
                              capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _device_record(compute) -> dict:
    info = compute.info
    return {"name": info.device.name.strip(), "platform": info.platform.name.strip(),
            "platform_version": info.platform.version.strip(),
            "driver": info.device.driver_version.strip(), "fp64": info.has_fp64}


def _require_unique_names(scenes) -> None:
    """Scene names key the results rows and the image folders, so two scenes may not share one."""
    seen = {}
    for scene in scenes:
        if scene.name in seen:
            raise InputError(scene.source or scene.name,
                             f"scene name '{scene.name}' is also the name of "
                             f"{seen[scene.name] or 'a built-in scene'}; rename one of the files")
        seen[scene.name] = scene.source


def _prepare_out(out: pathlib.Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(out, f"cannot create the output directory ({error.strerror})") from None
    if not os.access(out, os.W_OK):
        raise InputError(out, "the output directory is not writable")


class Runner:
    """Runs every cell not already in ``out``'s results table.

    A cell counts as done when a row with its (scene, estimator, spp, frame, seed) was made by the
    same estimator version on the same device; such rows are kept and not recomputed, so an
    interrupted run resumes and a rerun with more spp or seeds adds to the table.
    """

    def __init__(self, config: RunConfig):
        for spp in config.spp:
            if spp < 1:
                raise InputError(None, f"--spp values must be positive integers, got {spp}")
        if config.seeds < 1:
            raise InputError(None, f"--seeds must be at least 1, got {config.seeds}")
        self.config = config
        self.estimator_classes = [get_estimator_class(name) for name in config.estimators]
        self.scenes = [load_scene(name, sanitize=config.sanitize, env_res=config.env_res)
                       for name in config.scenes]
        _require_unique_names(self.scenes)
        for scene in self.scenes:
            if scene.environment.texels_fixed:
                print(f"iblbench: --sanitize replaced {scene.environment.texels_fixed} bad texels "
                      f"in {scene.environment.source}", file=sys.stderr)
        self.compute = get_compute(config.device)
        self.reference = Reference(self.compute)
        self.out = pathlib.Path(config.out)
        if self.out.exists() and not self.out.is_dir():
            raise InputError(self.out, "--out exists and is not a directory")
        self.rows = {cell_key(row): row for row in read_results(self.out)}
        self.resumed = 0
        self.manifest = self._new_manifest()

    def _new_manifest(self) -> dict:
        c = self.config
        return {
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            "config": {"scenes": list(c.scenes), "estimators": list(c.estimators),
                       "spp": list(c.spp), "seeds": c.seeds, "resolution": c.resolution,
                       "save_inputs": c.save_inputs, "sanitize": c.sanitize, "env_res": c.env_res},
            "protocol": PROTOCOL,
            "git_revision": _git_revision(),
            "versions": {"iblbench": _package_version("iblbench"), "python": platform.python_version(),
                         **{p: _package_version(p) for p in ("numpy", "pyopencl", "embreex",
                                                            "colour-science", "pandas")}},
            "estimator_versions": {cls.name: cls.version() for cls in self.estimator_classes},
            "device": _device_record(self.compute),
            "sanitized": {s.name: s.environment.texels_fixed for s in self.scenes},
            "stages": [],
            "skipped": [],
        }

    @property
    def total_cells(self) -> int:
        frames = sum(scene.environment.num_frames for scene in self.scenes)
        return frames * len(self.estimator_classes) * len(self.config.spp) * self.config.seeds

    def run(self):
        _prepare_out(self.out)
        self.manifest["status"] = "running"     # a killed run leaves this, not a missing manifest
        write_manifest(self.out, self.manifest)
        with tqdm(total=self.total_cells, unit="cell", disable=self._bar_disabled(),
                  desc="iblbench run") as bar:
            for scene in self.scenes:
                self._run_scene(scene, bar)
        table = write_results(self.out, list(self.rows.values()))
        self.manifest["status"] = "complete"
        self.manifest["resumed_cells"] = self.resumed
        write_manifest(self.out, self.manifest)
        return table

    def _bar_disabled(self):
        return None if self.config.progress is None else not self.config.progress

    def _run_scene(self, scene, bar) -> None:
        width, height = self.config.resolution or scene.resolution
        start = time.perf_counter()
        gbuffer = trace_gbuffer(scene.mesh, scene.material, scene.camera, width, height)
        self._stage(scene.name, None, "gbuffer", (time.perf_counter() - start) * 1e3)
        if gbuffer.covered == 0:
            raise InputError(scene.source or scene.name, "the camera sees no geometry")
        inputs = self.out / "inputs" / scene.name
        if self.config.save_inputs:
            gbuffer.save_npz(inputs / "gbuffer.npz")
        device_gbuffer = DeviceGBuffer(self.compute, gbuffer)
        required = {p for cls in self.estimator_classes for p in cls.requires}
        for product in PRODUCTS:
            if product not in required and product != "env":
                self.manifest["skipped"].append({"scene": scene.name, "stage": product,
                                                 "why": "no selected estimator requires it"})
        for frame in range(scene.environment.num_frames):
            env = scene.environment.frame(frame)
            if self.config.save_inputs:
                with atomic_path(inputs / f"env_f{frame}.npy") as tmp:
                    np.save(tmp, np.asarray(env, np.float32))
            cache = FrameCache(self.compute, env, frame)
            cache.require(sorted(required))
            for stage, ms in cache.timings_ms.items():
                self._stage(scene.name, frame, stage, ms)
            self._run_frame(scene.name, device_gbuffer, cache, bar)

    def _stage(self, scene: str, frame, stage: str, ms: float) -> None:
        self.manifest["stages"].append({"scene": scene, "frame": frame, "stage": stage, "ms": ms})

    def _run_frame(self, scene_name: str, gbuffer: DeviceGBuffer, cache: FrameCache, bar) -> None:
        images = self.out / "images" / scene_name / f"f{cache.frame}"
        reference = self.reference.image(gbuffer, cache)
        if self.reference.last_ms is None:
            self.manifest["skipped"].append({"scene": scene_name, "frame": cache.frame,
                                             "stage": "reference", "why": "cached"})
        else:
            self._stage(scene_name, cache.frame, "reference", self.reference.last_ms)
        mask = gbuffer.gbuffer.mask
        k = exposure(reference, mask)
        write_exr(images / "reference.exr", reference)
        write_preview(images / "reference.png", reference, k)
        for cls in self.estimator_classes:
            cells = [(spp, seed) for spp in self.config.spp for seed in range(self.config.seeds)
                     if not self._done(scene_name, cls, spp, cache.frame, seed)]
            self.resumed += self.config.seeds * len(self.config.spp) - len(cells)
            bar.update(self.config.seeds * len(self.config.spp) - len(cells))
            if not cells:
                continue
            estimator = cls()
            estimator.render(gbuffer, cache, min(self.config.spp), WARMUP_SEED)  # untimed warm-up
            # Per-frame builds only; a pool is drawn per render and timed as its "sample" stage.
            build_ms = sum(cache.timings_ms.get(p, 0.0) for p in ("upload",) + cls.requires
                           if p != "pool")
            for spp, seed in cells:
                start = time.perf_counter()
                estimate = estimator.render(gbuffer, cache, spp, seed)
                frame_ms = (time.perf_counter() - start) * 1e3
                metrics, delta_e = score(estimate, reference, mask)
                stem = f"{cls.name}_spp{spp}_s{seed}"
                write_exr(images / f"{stem}.exr", estimate.radiance)
                write_preview(images / f"{stem}.png", estimate.radiance, k)
                write_heat_map(images / f"{stem}_de76.png", delta_e)
                row = {
                    "scene": scene_name, "estimator": cls.name, "spp": spp,
                    "frame": cache.frame, "seed": seed, "estimator_version": cls.version(),
                    **metrics,
                    "time_ms_build": build_ms,
                    "time_ms_sample": estimate.timings_ms.get("sample", float("nan")),
                    "time_ms_shade": estimate.timings_ms.get("shade", float("nan")),
                    "time_ms_frame": frame_ms,
                    "device": self.compute.device_name, "protocol": PROTOCOL,
                }
                self.rows[cell_key(row)] = row
                bar.update()
            write_results(self.out, list(self.rows.values()))

    def _done(self, scene: str, cls, spp: int, frame: int, seed: int) -> bool:
        row = self.rows.get((scene, cls.name, spp, frame, seed))
        return (row is not None and row["estimator_version"] == cls.version()
                and row["device"] == self.compute.device_name)


def run(config: RunConfig):
    """Run a benchmark; returns the results table (also written under ``config.out``)."""
    return Runner(config).run()
