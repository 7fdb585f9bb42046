"""The reproduction archive keeps CSV files gzipped (deterministic bytes) and reads them back (issue 54.3)."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

from hptvsim.experiments.repro_archive import (
    archive_files,
    gzip_bytes,
    open_text,
    read_archived,
    restore_files,
)
from hptvsim.experiments.reproduce import (
    _training_metrics,
    archive_finished,
    load_plan,
    restore_archived,
)

ROOT = Path(__file__).resolve().parents[2]
SCALE_ARCHIVE = ROOT / "docs" / "reproduction" / "results-section5-scale"


def test_archiving_gzips_csv_with_the_same_bytes_every_time_and_restores_them_plain(tmp_path: Path) -> None:
    run, archive, back = tmp_path / "run", tmp_path / "archive", tmp_path / "back"
    (run / "eval").mkdir(parents=True)
    rows = "".join(f"0,source,{k},pursuer_0,{60 * k},{-0.5 * k}\n" for k in range(2000))
    (run / "episodes.csv").write_text("stage_index,stage,episode,agent,env_step,return\n" + rows)
    (run / "eval" / "source.json").write_text('{"stage": "source"}\n')
    files = ["episodes.csv", "eval/source.json", "missing.csv"]
    (archive / "episodes.csv").parent.mkdir(parents=True)
    (archive / "episodes.csv").write_text("an older hptvsim's plain copy\n")

    assert archive_files(run, archive, files)
    packed = archive / "episodes.csv.gz"
    assert not (archive / "episodes.csv").exists()  # the plain copy is replaced, not kept beside
    assert (archive / "eval" / "source.json").read_bytes() == (run / "eval" / "source.json").read_bytes()
    assert packed.read_bytes()[4:8] == b"\0\0\0\0"  # gzip header time 0: no date in the bytes
    assert packed.stat().st_size * 3 < (run / "episodes.csv").stat().st_size
    first = packed.read_bytes()
    assert not archive_files(run, archive, files)  # nothing changed: nothing written
    packed.unlink()
    assert archive_files(run, archive, files) and packed.read_bytes() == first == gzip_bytes(
        (run / "episodes.csv").read_bytes()
    )

    assert restore_files(archive, back, files)
    assert (back / "episodes.csv").read_bytes() == (run / "episodes.csv").read_bytes()
    assert read_archived(archive, "episodes.csv") == (run / "episodes.csv").read_bytes()
    with open_text(archive / "episodes.csv") as f:  # a reader handed the plain name finds the .gz
        assert f.readline().startswith("stage_index,")

    (archive / "episodes.csv").write_text("newer, plain\n")  # an older sweep archived after us
    assert read_archived(archive, "episodes.csv") == b"newer, plain\n"
    (back / "episodes.csv").write_text("the run folder's own\n")
    assert not restore_files(archive, back, files, missing_only=True)  # a finished run keeps its own
    assert (back / "episodes.csv").read_text() == "the run folder's own\n"


def test_a_run_restored_without_its_logs_gets_them_from_the_gzipped_archive(tmp_path: Path) -> None:
    """An older hptvsim restoring a gzipped archive leaves a finished run without its CSV logs
    (it copies plain files only); the report's next restore fills them in, so the training
    metrics are there again, equal to those read from the plain logs."""
    plan = load_plan(ROOT / "configs" / "reproduce" / "section5-scale.toml")
    archive, out = tmp_path / "archive", tmp_path / "out"
    shutil.copytree(SCALE_ARCHIVE / "base-seed0", archive / "base-seed0")
    assert (archive / "base-seed0" / "episodes.csv.gz").is_file()
    assert restore_archived(plan, out, archive, log=lambda _: None) == ["base-seed0"]
    run = out / "runs" / "base-seed0"
    plain = gzip.decompress((archive / "base-seed0" / "episodes.csv.gz").read_bytes())
    assert (run / "episodes.csv").read_bytes() == plain
    metrics = _training_metrics(run, plan.evaluation.last_episodes)
    assert set(metrics) == {"source", "transition", "target"}

    (run / "episodes.csv").unlink()
    (run / "curve.csv").unlink()
    assert _training_metrics(run, plan.evaluation.last_episodes) == {}
    assert restore_archived(plan, out, archive, log=lambda _: None) == ["base-seed0"]
    assert _training_metrics(run, plan.evaluation.last_episodes) == metrics
    assert restore_archived(plan, out, archive, log=lambda _: None) == []  # all there: nothing to do

    before = {p: p.read_bytes() for p in (archive / "base-seed0").rglob("*") if p.is_file()}
    archive_finished(plan, out, archive)  # archiving it again writes the same bytes
    assert {p: p.read_bytes() for p in (archive / "base-seed0").rglob("*") if p.is_file()} == before


def test_a_dt_step_restored_without_its_loss_log_gets_it_from_the_gzipped_archive(tmp_path: Path) -> None:
    """The same for a DT step: its ``run/loss.csv`` (gzipped in the archive) behind D1a/D1b."""
    from hptvsim.experiments.repro_dt import collect_dt, restore_dt

    plan = load_plan(ROOT / "configs" / "reproduce" / "section5-scale.toml")
    assert plan.dt is not None
    archive, out = tmp_path / "archive", tmp_path / "out"
    shutil.copytree(SCALE_ARCHIVE / "dt-base-seed0", archive / "dt-base-seed0")
    assert (archive / "dt-base-seed0" / "run" / "loss.csv.gz").is_file()
    assert restore_dt(plan.dt, out, archive, plan.fixed_episodes, log=lambda _: None) == ["dt-base-seed0"]
    metrics = collect_dt(plan.dt, out, plan.fixed_episodes).values[0]
    assert {"loss_change", "loss_ratio", "distance_slope"} <= set(metrics)

    (out / "dt" / "base-seed0" / "run" / "loss.csv").unlink()  # as an older hptvsim restores it
    assert "loss_ratio" not in collect_dt(plan.dt, out, plan.fixed_episodes).values[0]
    assert restore_dt(plan.dt, out, archive, plan.fixed_episodes, log=lambda _: None) == ["dt-base-seed0"]
    assert collect_dt(plan.dt, out, plan.fixed_episodes).values[0] == metrics
