"""``scripts/slam_suite.py`` hands the suite's ``--`` arguments to every run, but a stand-in run takes its depth
from the dataset and refuses ``--weights``: comparing two networks over the suite (``-- --weights W``) left the four
stand-in runs without a result."""

from pathlib import Path


def test_weights_reach_the_network_runs_and_not_the_standin_runs(script):
    suite = script("slam_suite")
    passthrough = ["--threads", "1", "--weights", "w.safetensors", "--config", "c.yaml", "--weights=v.safetensors"]
    standin = ("--depth-model", "standin")
    assert suite.run_arguments(standin, passthrough) == [*standin, "--threads", "1", "--config", "c.yaml"]
    assert suite.run_arguments((), passthrough) == passthrough
    true_prior = ("--depth-model", "true-prior")  # the network's decoder: it takes the weights
    assert suite.run_arguments(true_prior, passthrough) == [*true_prior, *passthrough]
    runs = {name: extra for name, _, extra in suite.RUNS}
    assert all(suite.run_arguments(runs[n], passthrough)[-2:] == ["--config", "c.yaml"]
               for n in runs if n.endswith("_standin"))


def test_the_table_reads_each_runs_scale_drift_and_marks_where_there_is_none(script, tmp_path):
    import json

    suite = script("slam_suite")
    base = dict(tracking_failures=0, frames=150, ate_sim3_rmse=0.2318, no_motion_ate_rmse_aligned=2.772,
                path_length_gt=14.116, rot_aligned_rmse_deg=0.5, rpe_trans_rmse=0.0486, rpe_trans_sim3_rmse=0.017,
                sim3_scale=1.77, fps=2.5)
    for name, drift in (("walk42", 1.4906), ("tum", None)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "result.json").write_text(json.dumps({**base, "scale_drift": drift}))
    (tmp_path / "walk").mkdir()
    (tmp_path / "walk" / "result.json").write_text(json.dumps(base))  # a run written before the metric
    lines = suite.table([tmp_path]).splitlines()
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    cells = {line.split("|")[1].strip(): [c.strip() for c in line.strip("|").split("|")] for line in lines[2:]}
    col = head.index("scale drift")
    assert cells["walk42"][col] == "1.49" and cells["tum"][col] == "-" and cells["walk"][col] == "-"
    assert all(len(c) == len(head) for c in cells.values())
    side = suite.table([tmp_path, tmp_path / "none"]).splitlines()  # two folders side by side, the second empty
    head2 = [c.strip() for c in side[0].strip("|").split("|")]
    walk42 = next([c.strip() for c in line.strip("|").split("|")] for line in side if line.startswith("| walk42 "))
    assert walk42[head2.index(f"{tmp_path.name}: scale drift")] == "1.49" and len(walk42) == len(head2)


def test_the_long_runs_are_made_only_when_asked_for(script):
    suite = script("slam_suite")

    def names(runs):
        return [r[0] for r in runs]

    default = names(suite.selected_runs(None))
    assert default == names(suite.RUNS) and "walk71" not in default
    assert names(suite.selected_runs(None, long=True)) == default + ["walk71", "walk71_standin"]
    assert names(suite.selected_runs(["walk42", "walk71"])) == ["walk42", "walk71"]  # --only reaches them too
    assert names(suite.selected_runs(["tum"], long=True)) == ["tum"]  # --only wins over --long
    assert all(data in suite.SEQUENCES for _, data, _ in suite.LONG_RUNS)
    assert suite.SEQUENCES["walk71"].frames == 450


def test_every_run_names_a_sequence_the_suite_can_make_and_no_two_sequences_share_a_seed(script):
    # Sequences are added as "never tuned on" (seeds 41-45, 51-56, 81-88): one rendered with a seed already in
    # the suite would repeat a room and path the settings were chosen on.
    suite = script("slam_suite")
    shared = {"hololens_dvmvs", "tum_fr1_rpy"}
    for _, data, _ in (*suite.RUNS, *suite.LONG_RUNS):
        base, at, variant = data.partition("@")
        assert base in suite.SEQUENCES or base in shared, data
        assert not at or variant in suite.VARIANTS, data
    seeds = [s.seed for s in suite.SEQUENCES.values()]
    assert len(seeds) == len(set(seeds)), sorted(seeds)
    names = [r[0] for r in (*suite.RUNS, *suite.LONG_RUNS)]
    assert len(names) == len(set(names))
    assert {"walk81", "corr82", "hh83", "ft84", "walk85", "corr86", "walk87", "hh88"} <= set(names)


def test_a_reordered_run_is_made_once_from_its_source_by_the_copy_script(script, tmp_path, monkeypatch):
    suite = script("slam_suite")
    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        out = Path(cmd[3])
        out.mkdir(parents=True)
        (out / "rgb.txt").write_text("")

    monkeypatch.setattr(suite.subprocess, "run", fake_run)
    first = suite.dataset_path("hololens_dvmvs@there-and-back", tmp_path)
    again = suite.dataset_path("hololens_dvmvs@there-and-back", tmp_path)
    assert first == again == tmp_path / "hololens_dvmvs@there-and-back" and len(calls) == 1
    assert calls[0][1].endswith("sequence_copy.py") and calls[0][2] == str(suite.SHARED / "hololens_dvmvs")
    assert calls[0][-2:] == ["--order", "there-and-back"]
    flipped = suite.dataset_path("tum_fr1_rpy@upside-down", tmp_path)
    assert flipped == tmp_path / "tum_fr1_rpy@upside-down" and calls[1][-1] == "--upside-down" and len(calls) == 2
