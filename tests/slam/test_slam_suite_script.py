"""``scripts/slam_suite.py`` hands the suite's ``--`` arguments to every run, but a stand-in run takes its depth
from the dataset and refuses ``--weights``: comparing two networks over the suite (``-- --weights W``) left the four
stand-in runs without a result."""


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
