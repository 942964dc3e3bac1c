"""One seed's course of `skyherd educate`, and its record in a run folder.

`teach_all(jobs, workers)` teaches the seeds, in worker processes when `workers` > 1, and
yields their results in seed order; `teach_seed(job)` teaches every lesson (policy.education.teach), and the monolithic DQN the same
lessons beside it (policy.education.monolith); both policies go to `job.policy_dir` as .npz files,
the lesson results come back as plain dicts. `lesson_rows` writes them as lessons.csv rows and
`results_from_rows` reads those rows back; `params_from_config` reads a run's hyper-parameters back
from its config.json; `read_finished_runs` gathers finished runs of one curriculum and one set of
hyper-parameters, so that they can be reported on again (`skyherd educate --from-run`).
"""

from __future__ import annotations

import csv
import dataclasses
import json
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.policy.dqn import DQNParams
from skyherd.policy.education.dqfd import DQfDParams
from skyherd.policy.education.teach import EduParams, MeasuresObjective

LEARNERS = ("educated", "monolith")
LESSON_METRICS = ("all_in_view_frac", "footprint_ratio", "ugv_losses")
LESSON_COLUMNS = ["learner", "seed", "after_lesson", "tested_lesson", *LESSON_METRICS, "passed",
                  "cpu_s"]  # fmt: skip


@dataclass(frozen=True)
class SeedJob:
    """One seed of a course (picklable: it runs in a worker process too)."""

    curriculum: Path  # the curriculum file, read again where the job runs
    params: EduParams  # its seed field is replaced by `seed`
    seed: int
    policy_dir: Path  # where educated_seed<seed>.npz and monolith_seed<seed>.npz go
    monolith: bool = True  # teach the monolithic DQN on this seed (when params.monolith)


def teach_seed(job: SeedJob) -> dict[str, Any]:
    """{"seed", "educated": [LessonResult as dict], "monolith": [...] (when taught)}; the
    policies are saved in job.policy_dir. One torch thread, in this process or a worker."""
    import torch

    torch.set_num_threads(1)
    from skyherd.policy.education.curriculum import load_curriculum
    from skyherd.policy.education.monolith import teach_monolith
    from skyherd.policy.education.teach import teach

    cur = load_curriculum(job.curriculum)
    p = dataclasses.replace(job.params, seed=job.seed)
    pol, res = teach(cur, p)
    out: dict[str, Any] = {"seed": job.seed, "educated": [dataclasses.asdict(r) for r in res]}
    pol.save(Path(job.policy_dir) / f"educated_seed{job.seed}.npz")
    if p.monolith and job.monolith:
        tgt = pol.meta.get("composite_target")
        target = (tgt["kind"], np.asarray(tgt["vector"])) if tgt else ("w", np.zeros(9))
        net, mres = teach_monolith(cur, p, res, target)
        net.meta.update({"seed": job.seed, "curriculum": pol.meta["curriculum"]})
        net.save(Path(job.policy_dir) / f"monolith_seed{job.seed}.npz")
        out["monolith"] = [dataclasses.asdict(r) for r in mres]
    return out


def teach_all(jobs: list[SeedJob], workers: int = 1) -> Iterator[dict[str, Any]]:
    """`teach_seed` of every job, in job order, on `workers` processes (1: this process)."""
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            yield from pool.map(teach_seed, jobs)
    else:
        yield from map(teach_seed, jobs)


def lesson_events(out: dict[str, Any]) -> list[dict[str, Any]]:
    """events.jsonl records of one seed's course: one per lesson taught, per learner."""
    return [
        {"event": "lesson", "learner": learner, "seed": out["seed"], "lesson": r["lesson"],
         "cpu_s": r["seconds"], "passed": r["passed"]}
        for learner in LEARNERS for r in out.get(learner, [])
    ]  # fmt: skip


def lesson_rows(out: dict[str, Any]) -> list[dict[str, Any]]:
    """lessons.csv rows (LESSON_COLUMNS) of one seed's course: every lesson's re-test after
    every lesson, per learner."""
    rows = []
    for learner in LEARNERS:
        for r in out.get(learner, []):
            for tested, m in r["retention"].items():
                rows.append({"learner": learner, "seed": out["seed"], "after_lesson": r["lesson"],
                             "tested_lesson": tested} | {k: m[k] for k in LESSON_METRICS}
                            | {"passed": r["passed"][tested], "cpu_s": r["seconds"]})  # fmt: skip
    return rows


def results_from_rows(rows: list[dict[str, str]]) -> list[dict[str, Any]]:
    """lessons.csv rows → the per-seed results `teach_seed` returns (the fields the report
    reads), for the seeds whose educated course is complete."""
    by: dict[int, dict[str, list]] = {}
    for r in rows:
        seq = by.setdefault(int(r["seed"]), {}).setdefault(r["learner"], [])
        if not seq or seq[-1]["lesson"] != r["after_lesson"]:
            seq.append({"lesson": r["after_lesson"], "retention": {}, "passed": {},
                        "seconds": float(r["cpu_s"]), "detail": {}})  # fmt: skip
        seq[-1]["retention"][r["tested_lesson"]] = {k: float(r[k]) for k in LESSON_METRICS}
        seq[-1]["passed"][r["tested_lesson"]] = r["passed"] == "True"
    n = max((len(v.get("educated", [])) for v in by.values()), default=0)
    return [{"seed": s, **v} for s, v in sorted(by.items()) if len(v.get("educated", [])) == n]


def params_from_config(cfg: dict[str, Any]) -> EduParams:
    """The EduParams of an educate run's config.json (KeyError / TypeError / ValueError if it
    is not one). Runs from before DQfD or the measures objective get those defaults."""
    hp = dict(cfg["hyper_parameters"])
    seed0 = hp.pop("seed", 0)
    d = hp.pop("dqn")
    dqn = dict(d, hidden=tuple(d["hidden"]), seed=0)
    if "dqfd" in hp:
        hp["dqfd"] = DQfDParams(**hp["dqfd"])
    if "measures" in hp:
        hp["measures"] = MeasuresObjective(**hp["measures"])
    return EduParams(dqn=DQNParams(**dqn), seed=seed0, **hp)


@dataclass
class FinishedRuns:
    """Finished educate runs read back, as one run of all their seeds."""

    params: EduParams  # the first run's
    curriculum: dict[str, Any]  # the first run's config.json "curriculum" entry
    results: list[dict[str, Any]]  # per seed, in seed order (results_from_rows)
    policy_dirs: dict[int, Path]  # seed → the policies/ folder of its run


def read_finished_runs(folders: list[Path], sha256: str) -> FinishedRuns:
    """The runs in `folders` (config.json, lessons.csv, policies/), taught the curriculum with
    this sha256 on the same hyper-parameters (the seed and the monolith aside) and on different
    seeds. ValueError, one line starting with the folder, for anything else."""
    p, cfg0, results, dirs = None, None, [], {}
    for src in folders:
        try:
            cfg = json.loads((src / "config.json").read_text())
            q = params_from_config(cfg)
            with open(src / "lessons.csv", newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{src}: not a finished educate run ({e})") from None
        if cfg["curriculum"]["sha256"] != sha256:
            raise ValueError(f"{src} was taught another curriculum (sha256 differs)")
        same = {"seed": 0, "monolith": True}  # a run without the monolith still compares
        if p is not None and dataclasses.replace(q, **same) != dataclasses.replace(p, **same):
            raise ValueError(f"{src}: other hyper-parameters than {folders[0]}")
        p, cfg0 = p or q, cfg0 or cfg
        for r in results_from_rows(rows):
            if r["seed"] in dirs:
                raise ValueError(f"{src}: seed {r['seed']} is also in another run")
            dirs[r["seed"]] = src / "policies"
            results.append(r)
    if not results:
        raise ValueError(f"{folders[0]}: lessons.csv has no finished seed")
    results.sort(key=lambda r: r["seed"])
    return FinishedRuns(p, cfg0["curriculum"], results, dirs)


def teach_into(
    folder: Any,
    curriculum: Path,
    p: EduParams,
    seeds: int,
    first_seed: int = 0,
    monolith_seeds: int | None = None,
    workers: int = 1,
    on_seed: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every seed's course into the run folder `folder` (runio.runfolder.RunFolder): the
    policies into policies/, lessons.csv and events.jsonl as each seed ends (then
    `on_seed(its result)`), lessons.json; the results in seed order. The monolithic DQN is
    taught on the first `monolith_seeds` seeds (None: all)."""
    from skyherd.runio.runfolder import CsvWriter, atomic_write_text

    pol_dir = folder.path / "policies"
    pol_dir.mkdir()
    n_mono = seeds if monolith_seeds is None else monolith_seeds
    jobs = [SeedJob(Path(curriculum), p, first_seed + s, pol_dir, s < n_mono) for s in range(seeds)]
    events, lessons = folder.events(), CsvWriter(folder.file("lessons.csv"), LESSON_COLUMNS)
    results = []
    for out in teach_all(jobs, workers):
        results.append(out)
        for row in lesson_rows(out):
            lessons.write(row)
        events.write_many(lesson_events(out))
        if on_seed:
            on_seed(out)
    lessons.close()
    atomic_write_text(folder.file("lessons.json"), json.dumps(results, indent=1, default=float))
    return results
