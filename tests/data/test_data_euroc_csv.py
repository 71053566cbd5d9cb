"""EuRoC CSV trajectories: reading the ASL ground-truth layout, round trips, and malformed files."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from codeslam.data.euroc_csv import read_euroc_csv, seconds_to_ns, write_euroc_csv
from codeslam.data.trajectory import Trajectory, poses_from_tum_rows
from codeslam.errors import DatasetError

# Two lines in the layout of EuRoC MH_01 mav0/state_groundtruth_estimate0/data.csv (17 columns).
ASL_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
    "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
)
ASL_LINES = (
    "1403636580838555648,4.688319,-1.786938,0.783338,0.534108,-0.153029,-0.827383,-0.082152,"
    "-0.027876,0.033207,0.800006,-0.003172,0.021267,0.078502,-0.025266,0.136696,0.075593\n"
    "1403636580843555328,4.688177,-1.786770,0.787350,0.534640,-0.152990,-0.826976,-0.082863,"
    "-0.029272,0.033992,0.804771,-0.003172,0.021267,0.078502,-0.025266,0.136696,0.075593\n"
)


def test_reads_asl_groundtruth_with_w_first_quaternion(tmp_path):
    p = tmp_path / "data.csv"
    p.write_text(ASL_HEADER + ASL_LINES)
    traj = read_euroc_csv(p)
    assert len(traj) == 2
    assert traj.timestamps[0] == 1403636580838555648 / 1_000_000_000
    assert traj.timestamps[1] - traj.timestamps[0] == pytest.approx(0.005, abs=1e-6)
    # Same pose built from the TUM (x, y, z, w) order by hand.
    expected = poses_from_tum_rows(np.array([[4.688319, -1.786938, 0.783338, -0.153029, -0.827383, -0.082152,
                                              0.534108]]))
    torch.testing.assert_close(traj.poses[0], expected[0], rtol=0, atol=1e-12)
    R = traj.poses[0, :3, :3]
    torch.testing.assert_close(R @ R.T, torch.eye(3, dtype=torch.float64), rtol=0, atol=1e-12)


def test_round_trip_is_exact_in_seconds(tmp_path):
    gen = torch.Generator().manual_seed(0)
    n = 50
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    rows = torch.cat([torch.randn(n, 3, generator=gen, dtype=torch.float64) * 5, q], -1).numpy()
    stamps = 1403636580.0 + np.cumsum(np.random.default_rng(0).uniform(0.001, 0.1, n))
    traj = Trajectory(stamps, poses_from_tum_rows(rows))
    p = tmp_path / "est.csv"
    write_euroc_csv(p, traj)
    back = read_euroc_csv(p)
    # A float64 Unix time cannot hold every nanosecond; the writer rounds to the nearest ns and the reader
    # divides exactly, which gives back the same float.
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)
    torch.testing.assert_close(back.poses, traj.poses, rtol=0, atol=5e-9)
    # Timestamps are written as integers in ns, the quaternion w first.
    first = p.read_text().splitlines()[1].split(",")
    assert first[0] == str(seconds_to_ns(stamps[0]))
    assert float(first[4]) == pytest.approx(abs(float(first[4])))  # writer uses w >= 0


def test_seconds_to_ns_is_exact():
    assert seconds_to_ns(1.5) == 1_500_000_000
    t = 1403636580838555648 / 1_000_000_000
    assert abs(seconds_to_ns(t) - 1403636580838555648) < 200  # float64 resolution at 1.4e9 s is ~240 ns
    assert seconds_to_ns(t) / 1_000_000_000 == t


@pytest.mark.parametrize(
    ("body", "msg"),
    [
        ("1403636580838555648,4.6,-1.7,0.7,1,0,0\n", "data.csv:2: expected"),
        ("1403636580838555648,4.6,-1.7,abc,1,0,0,0\n", "data.csv:2: not a number"),
        ("1403636580838555648,4.6,-1.7,nan,1,0,0,0\n", "data.csv:2: non-finite"),
        ("1403636580838555648,4.6,-1.7,0.7,0,0,0,0\n", "data.csv:2: zero quaternion"),
        ("1403636580838555648,4.6,-1.7,0.7,1,0,0,0\n1403636580838555648,4.6,-1.7,0.7,1,0,0,0\n",
         "data.csv:3: timestamp"),
        ("", "holds no poses"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, body, msg):
    p = tmp_path / "data.csv"
    p.write_text("#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z\n" + body)
    with pytest.raises(DatasetError, match=msg):
        read_euroc_csv(p)


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        read_euroc_csv(tmp_path / "nope.csv")
