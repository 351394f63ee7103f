"""Run metrics against flights built from a known truth (gcs.report.metrics)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gcs.report.flight_record import FlightRecord
from gcs.report.metrics import (
    compute_metrics,
    consensus_errors,
    reconvergence,
    separation,
    tracking_errors,
    tracking_from_positions,
    true_descriptors,
)
from protocols.model.frames import FloatArray, rot_zyx

DT = 0.02
RECT = np.array([[3.0, 1.5, 0.0], [3.0, -1.5, 0.0], [-3.0, 1.5, 0.0], [-3.0, -1.5, 0.0]])
S_RECT = (9.0, 2.25, 0.0)  # population variances of RECT along x, y, z


def grid(duration_s: float) -> FloatArray:
    return np.round(np.arange(round(duration_s / DT)) * DT, 9)


def centre_path(t: FloatArray) -> FloatArray:
    return np.stack([2.0 * t, np.sin(t), -5.0 - 0.1 * t], axis=1)


def formation(t: FloatArray, offsets: FloatArray = RECT, yaw: FloatArray | None = None):
    """Rigid formation (T, N, 3) on ``centre_path`` turned by ``yaw`` (T,), and its a_d (T, 9)."""
    yaw = np.zeros_like(t) if yaw is None else yaw
    rot = np.stack([rot_zyx(float(y), 0.0, 0.0) for y in yaw])
    pos = centre_path(t)[:, None, :] + np.einsum("tij,nj->tni", rot, offsets)
    desired = np.zeros((t.size, 9))
    desired[:, :3] = centre_path(t)
    desired[:, 5] = yaw
    desired[:, 6:] = S_RECT
    return pos, desired


def make_record(t, pos, desired, **kw) -> FlightRecord:
    n = pos.shape[1]
    fields = {
        "velocity_ned_m_s": np.zeros_like(pos),
        "euler_rad": np.zeros_like(pos),
        "thrust_n": np.full((t.size, n), 3.3),
        "moments_nm": np.zeros_like(pos),
        "estimate": np.full((t.size, n, 9), np.nan),
        "member": np.ones((t.size, n), dtype=bool),
        "airborne": np.ones((t.size, n), dtype=bool),
        "neighbours": np.full((t.size, n), n - 1),
    }
    fields.update(kw)
    return FlightRecord(t_s=t, position_ned_m=pos, desired=desired, **fields)


def track(rec: FlightRecord, settle_s: float = 0.0) -> dict:
    return tracking_errors(rec.t_s, true_descriptors(rec), rec.desired, settle_s)


# --- tracking -------------------------------------------------------------------------------


def test_rigid_formation_on_its_own_descriptors_has_zero_tracking_error():
    t = grid(10.0)
    pos, desired = formation(t, yaw=0.4 * np.sin(t))
    m = track(make_record(t, pos, desired), settle_s=2.0)
    assert m["n_samples"] == np.sum(t >= 2.0)
    for stat in m["descriptors"].values():
        assert stat["rms"] < 1e-9 and stat["max"] < 1e-9
        assert stat["n"] == m["n_samples"]
    assert m["centroid_m"]["max"] < 1e-9 and m["shape_m2"]["max"] < 1e-9


def test_offset_formation_gives_exact_centroid_error():
    t = grid(5.0)
    pos, desired = formation(t)
    m = track(make_record(t, pos + np.array([0.06, 0.08, 0.0]), desired))
    assert m["centroid_m"]["rms"] == pytest.approx(0.1, abs=1e-12)
    assert m["centroid_m"]["max"] == pytest.approx(0.1, abs=1e-12)
    assert m["descriptors"]["mu_x_m"]["rms"] == pytest.approx(0.06, abs=1e-12)
    assert m["descriptors"]["mu_y_m"]["max"] == pytest.approx(0.08, abs=1e-12)
    assert m["descriptors"]["mu_z_m"]["rms"] < 1e-12
    assert m["shape_m2"]["max"] < 1e-12


def test_shape_error_is_rms_over_the_three_variances():
    t = grid(2.0)
    pos, desired = formation(t, offsets=RECT * [1.1, 1.0, 1.0])
    m = track(make_record(t, pos, desired))
    e1 = 9.0 * 1.21 - 9.0
    assert m["descriptors"]["s_length_m2"]["rms"] == pytest.approx(e1, abs=1e-9)
    assert m["descriptors"]["s_width_m2"]["max"] < 1e-9
    assert m["shape_m2"]["rms"] == pytest.approx(e1 / math.sqrt(3), abs=1e-9)


def test_angle_error_is_wrapped_across_pi_and_reported_in_degrees():
    t = grid(1.0)
    pos, desired = formation(t, yaw=np.full(t.size, np.pi + 0.01))
    desired[:, 5] = np.pi - 0.01
    yaw = track(make_record(t, pos, desired))["descriptors"]["yaw_rad"]
    assert yaw["rms"] == pytest.approx(0.02, abs=1e-9)
    assert yaw["max_deg"] == pytest.approx(math.degrees(0.02), abs=1e-7)


def test_orientation_is_masked_while_heading_is_undefined_but_centre_is_not():
    t = grid(2.0)
    square = np.array([[2.0, 2.0, 0.0], [2.0, -2.0, 0.0], [-2.0, 2.0, 0.0], [-2.0, -2.0, 0.0]])
    pos, desired = formation(t, offsets=square, yaw=np.full(t.size, 0.3))
    m = track(make_record(t, pos, desired))
    for name in ("roll_rad", "pitch_rad", "yaw_rad"):
        assert m["descriptors"][name] == {"rms": None, "max": None, "n": 0}
    assert m["descriptors"]["mu_x_m"]["n"] == t.size


def test_errors_before_settle_time_are_ignored():
    t = grid(6.0)
    pos, desired = formation(t)
    pos[t < 3.0] += 5.0
    m = track(make_record(t, pos, desired), settle_s=3.0)
    assert m["centroid_m"]["max"] < 1e-12
    assert m["n_samples"] == np.sum(t >= 3.0)


def test_true_descriptors_use_members_only_and_need_two():
    t = grid(2.0)
    five = np.vstack([RECT, [0.0, 0.0, 0.0]])
    pos, desired = formation(t, offsets=five)
    member = np.ones((t.size, 5), dtype=bool)
    member[t >= 1.0, 4] = False
    pos[t >= 1.0, 4] += [0.0, 0.0, 30.0]  # the lost drone falls away
    member[-1, 1:] = False
    a = true_descriptors(make_record(t, pos, desired, member=member))
    assert a[0, 6] == pytest.approx(4 * 9.0 / 5)
    assert a[-2, 6] == pytest.approx(9.0)
    np.testing.assert_allclose(a[-2, :3], centre_path(t)[-2], atol=1e-12)
    assert np.all(np.isnan(a[-1]))


def test_tracking_from_positions_matches_tracking_of_the_record():
    t = grid(3.0)
    pos, desired = formation(t, yaw=0.2 * t)
    rec = make_record(t, pos + 0.05, desired)
    assert tracking_from_positions(t, pos + 0.05, rec.member, desired, 1.0) == track(rec, 1.0)


# --- consensus ------------------------------------------------------------------------------


def test_consensus_error_equals_a_known_estimate_bias():
    t = grid(4.0)
    pos, desired = formation(t, yaw=np.full(t.size, 0.2))
    rec = make_record(t, pos, desired)
    bias = np.array([0.01, -0.02, 0.03, 0.001, -0.002, 0.003, 0.1, -0.2, 0.05])
    est = true_descriptors(rec)[:, None, :] + bias
    est = np.repeat(est, 4, axis=1)
    est[:, 3] = 1e6  # drone 3 is not a member: ignored
    member = np.ones((t.size, 4), dtype=bool)
    member[:, 3] = False
    est[5, 2] = np.nan  # a member without an estimate
    m = consensus_errors(t, true_descriptors(rec), est, member, settle_s=0.0)
    for k, stat in enumerate(m["descriptors"].values()):
        assert stat["rms"] == pytest.approx(abs(bias[k]), rel=1e-6)
        assert stat["max"] == pytest.approx(abs(bias[k]), rel=1e-6)
        assert stat["n"] == 3 * t.size - 1
    assert m["centroid_m"]["rms"] == pytest.approx(np.linalg.norm(bias[:3]), rel=1e-9)
    assert m["shape_m2"]["rms"] == pytest.approx(np.sqrt(np.mean(bias[6:] ** 2)), rel=1e-9)
    assert m["n_missing_estimates"] == 1
    assert m["per_agent"][3]["centroid_rms_m"] is None


def test_consensus_per_agent_centroid_rms():
    t = grid(2.0)
    pos, desired = formation(t)
    a = true_descriptors(make_record(t, pos, desired))
    est = np.repeat(a[:, None, :], 4, axis=1)
    est[..., 0] += 0.01 * np.arange(1, 5)
    m = consensus_errors(t, a, est, np.ones((t.size, 4), dtype=bool), settle_s=0.0)
    rms = [agent["centroid_rms_m"] for agent in m["per_agent"]]
    np.testing.assert_allclose(rms, 0.01 * np.arange(1, 5), rtol=1e-9)
    assert m["descriptors"]["mu_x_m"]["rms"] == pytest.approx(0.01 * math.sqrt(7.5), rel=1e-9)
    assert m["descriptors"]["mu_x_m"]["max"] == pytest.approx(0.04, rel=1e-9)


# --- re-convergence -------------------------------------------------------------------------


def decaying_flight(t, faults_and_taus):
    """Formation with a centre error 0.5 exp(-(t - t_f)/tau) after each fault; exact estimates."""
    pos, desired = formation(t)
    err = np.zeros(t.size)
    for t_f, tau in faults_and_taus:
        err = np.where(t >= t_f, 0.5 * np.exp(-(t - t_f) / tau), err)
    pos = pos + err[:, None, None] * [1.0, 0.0, 0.0]
    rec = make_record(t, pos, desired)
    a = true_descriptors(rec)
    rec.estimate = np.repeat(a[:, None, :], 4, axis=1)
    return rec, a


def reconv(rec, a, faults):
    return reconvergence(rec.t_s, a, rec.desired, rec.estimate, rec.member, faults)


def test_reconvergence_time_of_an_exponential_decay_within_one_sample():
    t = grid(30.0)
    rec, a = decaying_flight(t, [(10.0, 2.0)])
    (item,) = reconv(rec, a, [(10.0, "drone 2 lost")])
    assert item["time_to_reconverge_s"] == pytest.approx(2.0 * math.log(10.0), abs=DT)
    assert item["peak_centroid_error_m"] == pytest.approx(0.5, rel=1e-9)
    assert item["description"] == "drone 2 lost"


def test_reconvergence_needs_the_condition_to_hold_to_the_end_of_the_window():
    t = grid(30.0)
    rec, a = decaying_flight(t, [(10.0, 2.0)])
    bump = (t >= 20.0) & (t < 20.5)
    rec.position_ned_m[bump] += [0.1, 0.0, 0.0]
    a = true_descriptors(rec)
    rec.estimate = np.repeat(a[:, None, :], 4, axis=1)
    (item,) = reconv(rec, a, [(10.0, "fault")])
    assert item["time_to_reconverge_s"] == pytest.approx(10.5, abs=1e-9)


def test_window_ends_at_the_next_fault_and_a_short_final_hold_does_not_count():
    t = grid(30.0)
    tau_late = 4.5 / math.log(10.0)  # crosses 5 cm 4.5 s after t = 25: only 0.5 s before the end
    rec, a = decaying_flight(t, [(10.0, 2.0), (12.0, 2.0), (25.0, tau_late)])
    first, second, third = reconv(rec, a, [(25.0, "c"), (10.0, "a"), (12.0, "b")])
    assert [first["t_s"], second["t_s"], third["t_s"]] == [10.0, 12.0, 25.0]
    assert first["time_to_reconverge_s"] is None and first["window_end_s"] == 12.0
    assert second["time_to_reconverge_s"] == pytest.approx(2.0 * math.log(10.0), abs=DT)
    assert third["time_to_reconverge_s"] is None


def test_reconvergence_requires_every_member_estimate_to_agree():
    t = grid(20.0)
    rec, a = decaying_flight(t, [(5.0, 1.0)])
    rec.estimate[:, 2, 0] += 0.06
    assert reconv(rec, a, [(5.0, "x")])[0]["time_to_reconverge_s"] is None
    rec.member[:, 2] = False  # the biased agent is no longer a member: no longer counted
    assert reconv(rec, a, [(5.0, "x")])[0]["time_to_reconverge_s"] is not None


# --- separation and collisions --------------------------------------------------------------


def test_min_separation_of_two_approaching_drones_and_grounded_pairs_ignored():
    t = grid(10.0)
    d = 0.5 + 0.2 * np.abs(t - 5.0)
    pos = np.zeros((t.size, 5, 3))
    pos[:, 0, 1], pos[:, 1, 1] = -d / 2, d / 2
    pos[:, 2] = [20.0, 0.0, -3.0]
    pos[:, 3], pos[:, 4] = [40.0, 0.0, 0.0], [40.0, 0.1, 0.0]  # on the ground, 0.1 m apart
    airborne = np.ones((t.size, 5), dtype=bool)
    airborne[:, 3:] = False
    sep, collisions = separation(t, pos, airborne)
    assert sep == {"min_m": pytest.approx(0.5), "t_s": pytest.approx(5.0), "pair": [0, 1]}
    assert collisions["count"] == 0


def test_collisions_are_counted_once_per_pair_per_contact_across_chunks():
    t = grid(10.0)
    dip = lambda tc: 0.9 * np.exp(-(((t - tc) / 0.3) ** 2))  # noqa: E731
    pos = np.zeros((t.size, 3, 3))
    pos[:, 1, 0] = 1.0 - dip(3.0) - dip(7.0)  # pair (0, 1) touches twice
    pos[:, 2] = [50.0, 0.0, 0.0]
    pos[:, 2, 0] -= 49.0 * np.exp(-(((t - 5.0) / 0.5) ** 2)) * 1.0  # (1, 2) or (0, 2) once
    airborne = np.ones((t.size, 3), dtype=bool)
    whole = separation(t, pos, airborne, collision_distance_m=0.3)[1]
    chunked = separation(t, pos, airborne, collision_distance_m=0.3, chunk_samples=7)[1]
    assert whole == chunked
    pairs = sorted(tuple(e["pair"]) for e in whole["episodes"])
    assert pairs == [(0, 1), (0, 1), (1, 2)]
    assert whole["count"] == 3


def _separation_over_every_pair(t, pos, airborne, c=0.3):  # type: ignore[no-untyped-def]
    """The separation as an (T, N, N) matrix of norms over the upper triangle: the reference."""
    n = pos.shape[1]
    d = np.linalg.norm(pos[:, :, None, :] - pos[:, None, :, :], axis=-1)
    valid = airborne[:, :, None] & airborne[:, None, :] & np.triu(np.ones((n, n), bool), 1)
    d = np.where(valid & np.isfinite(d), d, np.inf)
    k, i, j = np.unravel_index(np.argmin(d), d.shape)
    close = d < c
    rising = close & ~np.concatenate([np.zeros((1, n, n), bool), close[:-1]])
    episodes = [
        {"t_s": float(t[k_]), "pair": [int(i_), int(j_)]} for k_, i_, j_ in np.argwhere(rising)
    ]
    return float(d[k, i, j]), float(t[k]), [int(i), int(j)], episodes


def test_separation_over_the_pairs_gives_the_matrix_of_norms_figures_bit_for_bit():
    """The pairs i < j as one axis: the same minimum (its bits, time and pair, the first of ties),
    the same collision episodes in the same order, with grounded drones and lost samples (NaN)."""
    rng = np.random.default_rng(5)
    t = grid(6.0)
    pos = rng.uniform(-3.0, 3.0, size=(t.size, 12, 3))
    pos[40:60, 3] = pos[40:60, 7] + 0.01  # a contact, and ties across samples
    pos[100:110, 5] = np.nan
    airborne = rng.random((t.size, 12)) > 0.2
    best, collisions = separation(t, pos, airborne, collision_distance_m=0.3, chunk_samples=17)
    min_m, t_min, pair, episodes = _separation_over_every_pair(t, pos, airborne)
    assert (best["min_m"], best["t_s"], best["pair"]) == (min_m, t_min, pair)
    assert collisions["episodes"] == episodes[:100] and collisions["count"] == len(episodes)


@pytest.mark.parametrize("chunk", [None, 1, 7, 25])
def test_separation_measuring_only_the_near_pairs_gives_every_pairs_figures(chunk):
    """A 40-drone swarm on the move (random walks, some contacts, ties, grounded drones, lost
    samples): measuring in each chunk only the pairs whose boxes come within the bound gives the
    minimum, its pair and time and the collision episodes of every pair, bit for bit."""
    rng = np.random.default_rng(11)
    t = grid(8.0)
    n = 40
    start = np.stack(np.meshgrid(np.arange(8) * 2.5, np.arange(5) * 2.5, [0.0]), -1).reshape(-1, 3)
    pos = start[None] + np.cumsum(rng.normal(0.0, 0.05, (t.size, n, 3)), axis=0)
    pos[30:70, 12] = pos[30:70, 13] + [0.1, 0.0, 0.0]  # a collision and a run of tied minima
    pos[120:150, 20] = pos[120:150, 28] + [0.25, 0.0, 0.0]
    pos[80:90, 5] = np.nan
    airborne = np.ones((t.size, n), dtype=bool)
    airborne[:50, 30:] = False  # these take off late
    airborne[rng.random((t.size, n)) < 0.02] = False
    best, collisions = separation(t, pos, airborne, chunk_samples=chunk)
    min_m, t_min, pair, episodes = _separation_over_every_pair(t, pos, airborne)
    assert (best["min_m"], best["t_s"], best["pair"]) == (min_m, t_min, pair)
    assert collisions["episodes"] == episodes[:100] and collisions["count"] == len(episodes)
    assert collisions["count"] >= 2


def test_separation_measures_every_pair_when_the_nearest_boxes_never_fly_together():
    """Drones 0 and 1 share a spot but are never airborne at the same sample: their boxes set a
    bound no measured pair meets, so the chunk is measured whole (the others are 5 m apart)."""
    t = grid(2.0)
    pos = np.zeros((t.size, 4, 3))
    pos[:, 2] = [5.0, 0.0, 0.0]
    pos[:, 3] = [5.0, 5.0, 0.0]
    airborne = np.ones((t.size, 4), dtype=bool)
    airborne[::2, 0] = False
    airborne[1::2, 1] = False
    best, collisions = separation(t, pos, airborne, chunk_samples=10)
    min_m, t_min, pair, episodes = _separation_over_every_pair(t, pos, airborne)
    assert (best["min_m"], best["t_s"], best["pair"]) == (min_m, t_min, pair) == (5.0, 0.0, [1, 2])
    assert collisions["count"] == len(episodes) == 0


# --- the whole report -----------------------------------------------------------------------


def test_compute_metrics_is_json_and_reports_losses_tilt_thrust_and_extra():
    t = grid(4.0)
    pos, desired = formation(t)
    euler = np.zeros_like(pos)
    euler[50, 2, :2] = [0.1, 0.2]
    thrust = np.full((t.size, 4), 3.0)
    thrust[60, 1] = 6.0
    member = np.ones((t.size, 4), dtype=bool)
    member[t >= 2.0, 3] = False
    rec = make_record(
        t, pos, desired, euler_rad=euler, thrust_n=thrust, member=member, lost_at_s={3: 2.0}
    )
    rec.estimate = np.repeat(true_descriptors(rec)[:, None, :], 4, axis=1)
    m = compute_metrics(
        rec, 1.0, [(2.0, "drone 4 lost")], max_thrust_n=6.7, extra={"real_time_factor": 3.5}
    )
    json.dumps(m, allow_nan=False)
    assert m["n_samples"] == t.size and m["real_time_factor"] == 3.5
    assert m["drones_lost"] == [{"index": 3, "sysid": 4, "t_s": 2.0}]
    tilt = math.degrees(math.acos(math.cos(0.1) * math.cos(0.2)))
    assert m["max_tilt_deg"]["value"] == pytest.approx(tilt)
    assert (m["max_tilt_deg"]["sysid"], m["max_tilt_deg"]["t_s"]) == (3, t[50])
    assert m["max_thrust_ratio"]["value"] == pytest.approx(6.0 / 6.7)
    assert m["separation"]["min_m"] == pytest.approx(3.0)
    (after_loss,) = m["reconvergence"]  # three corners of the rectangle: centre off by 1.118 m
    assert after_loss["time_to_reconverge_s"] is None
    assert after_loss["peak_centroid_error_m"] == pytest.approx(math.sqrt(1.25))
    with pytest.raises(ValueError, match="clash"):
        compute_metrics(rec, 1.0, extra={"tracking": 1})


def test_the_true_descriptors_of_all_samples_at_once_are_each_samples_own() -> None:
    """descriptors_of works on every sample at once (blocks of them); each row is the swarm
    frame of that sample's members with a position (protocols.model.descriptors.descriptors),
    the world's axes where the desired orientation is not finite, NaN with fewer than two
    members; and heading_mask is heading_defined's rule row by row."""
    from gcs.report import metrics
    from gcs.report.metrics import descriptors_of, heading_mask
    from protocols.model.descriptors import descriptors, heading_defined

    rng = np.random.default_rng(7)
    t_n, n = 300, 7
    pos = rng.normal(0.0, 2.0, (t_n, n, 3)) * np.array([3.0, 1.0, 0.2])
    member = rng.random((t_n, n)) > 0.2
    member[:5] = False  # nobody
    member[5, :] = [True] + [False] * (n - 1)  # one drone
    pos[10:20, 2] = np.nan  # a drone with no position
    desired = rng.normal(0.0, 0.5, (t_n, 9))
    desired[30:40, 4] = np.nan  # no desired orientation: the world's axes
    desired[50:60, 6:9] = [2.0, 2.02, 0.1]  # length and width tied
    got = descriptors_of(pos, member, desired)
    small = metrics._BLOCK_VALUES
    try:
        metrics._BLOCK_VALUES = 3 * n  # three samples a block: the same rows
        np.testing.assert_array_equal(descriptors_of(pos, member, desired), got)
    finally:
        metrics._BLOCK_VALUES = small
    for k in range(t_n):
        use = member[k] & np.all(np.isfinite(pos[k]), axis=1)
        if use.sum() < 2:
            assert np.isnan(got[k]).all()
            continue
        d = desired[k] if np.all(np.isfinite(desired[k])) else None
        np.testing.assert_allclose(got[k], descriptors(pos[k][use], d), rtol=1e-9, atol=1e-9)
    ties = got.copy()
    ties[50:60, 6:9] = [2.0, 2.02, 0.1]
    want = [bool(np.all(np.isfinite(a[6:9]))) and heading_defined(a[6:9]) for a in ties]
    assert heading_mask(ties).tolist() == want
    assert not heading_mask(ties)[50:60].any() and not heading_mask(ties)[:5].any()
