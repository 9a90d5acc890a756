"""Run the SLAM system over a sequence folder and write the results files (`dynaslam2 run`)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from tqdm import tqdm

from dynaslam2.config import load_config
from dynaslam2.config_tree import to_dict
from dynaslam2.io.results import ResultsWriter
from dynaslam2.io.sequence import open_sequence
from dynaslam2.system import System
from dynaslam2.versions import package_versions


def _gtsam_version() -> str:
    try:
        return version("gtsam")
    except PackageNotFoundError:  # built from source without package metadata
        return "unknown"


def run_sequence(seq_path, mode: str, out, config_path=None, overrides=(), overwrite: bool = False,
                 progress: bool = True) -> Path:
    """Process every frame of the sequence at `seq_path` in `mode`; write `poses.txt`,
    `status.jsonl`, `timing.csv` (and in `dynamic` mode `objects.jsonl`, `tracks.txt`) into `out`
    frame by frame (a crash keeps what was written).

    Bad input (missing or malformed files, unknown config keys, an unavailable mode) raises InputError
    before anything is written.
    """
    config = load_config(config_path, list(overrides) + [f"mode={mode}"])
    sequence = open_sequence(seq_path)
    system = System(config, sequence.camera)
    if len(sequence):
        system.frontend.check(sequence[0])  # a sequence this mode cannot run: one error, nothing written
    run_info = {"mode": mode, "sequence": str(Path(seq_path).resolve()),
                "sequence_fingerprint": sequence.fingerprint(), "config": to_dict(config),
                "versions": package_versions(gtsam=_gtsam_version())}
    with ResultsWriter(out, overwrite=overwrite, run_info=run_info) as writer:
        bar = tqdm(total=len(sequence), desc=f"run {mode}", unit="frame", disable=not progress)
        total_ms = 0.0
        try:
            for i in range(len(sequence)):
                estimate = system.process(sequence[i])
                writer.write_frame(i, estimate.T_w_c, estimate.status(), estimate.timing_ms)
                if mode == "dynamic":
                    writer.write_objects(i, estimate.T_w_c, estimate.objects)
                total_ms += estimate.timing_ms["total"]
                bar.set_postfix_str(f"{estimate.state}, SLAM {1000.0 * (i + 1) / max(total_ms, 1e-3):.1f} fps",
                                    refresh=False)
                bar.update(1)
        finally:
            bar.close()
    return Path(out)
