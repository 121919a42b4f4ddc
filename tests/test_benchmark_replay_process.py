"""benchmarks/replay_process.py on a small log: every figure is measured (the child's hook
finds both pipeline stages of the command as it runs), with its best, median and the load
beside it. Orders only, never a time bound: the times are the benchmark's business."""

from __future__ import annotations


def test_the_replay_process_benchmark_gives_best_median_and_load(tmp_path) -> None:
    from benchmarks.replay_process import measure

    figures = {f.key: f for f in measure(n_frames=20_000, repeat=3, workdir=str(tmp_path))}
    for name in ("none", "csv", "parquet"):
        fig = figures[f"replay_process_{name}"]
        assert not fig.error, fig.error
        extra = fig.extra
        assert 0 < extra["seconds"] <= extra["median_seconds"]
        assert 0 < extra["anchor_seconds"] <= extra["anchor_median_seconds"]
        assert extra["load"].startswith("load ") and f"median {extra['median_seconds']:.2f} s" in (
            fig.detail
        )
    for key in ("replay_first_step", "replay_first_row"):
        noted = figures[key].extra
        assert set(noted) == {"none", "csv", "parquet"}, key  # both stages noted in each run
    assert all(
        figures["replay_first_step"].extra[n] < figures["replay_first_row"].extra[n]
        for n in ("none", "csv", "parquet")
    )  # in each run the first stage's first step ends before the second stage's
