"""The push planner example's cost terms (no server needed)."""

import argparse
import importlib.util
import json
import os
import tempfile
import unittest

import numpy as np

_PATH = os.path.join(os.path.dirname(__file__), "..", "examples", "push_planner.py")
_spec = importlib.util.spec_from_file_location("push_planner", _PATH)
planner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(planner)


class SideCost(unittest.TestCase):
    def test_zero_behind_the_box_and_larger_on_the_wrong_side(self):
        goal = np.array([1.0, 0.0])
        steps = 3
        traj = np.zeros((2, steps, 2, 7))  # box at the origin, not moving
        behind = -(planner.HALF + planner.PUSHER_HALF)
        paths = np.zeros((2, steps, 7))
        paths[0, :, 0] = [behind - 0.2, behind - 0.1, behind]  # reaches the pushing side
        paths[1, :, 0] = [-behind, -behind + 0.1, -behind + 0.2]  # stays on the goal side
        cost = planner.side_cost(traj, paths, goal)
        self.assertAlmostEqual(cost[0], 0.0, places=9)
        self.assertAlmostEqual(cost[1], 2 * -behind, places=9)


class Risk(unittest.TestCase):
    def test_the_box_spread_adds_in_quadrature_over_the_horizon(self):
        spread = np.zeros((2, 4, 2, 2))  # [candidates, steps, objects, (m, deg)]
        spread[0, :, planner.BOX, 0] = [0.03, 0.04, 0.0, 0.0]
        spread[1, :, planner.BOX, 1] = 5.0  # orientation only: no position risk
        spread[1, :, planner.PUSHER, 0] = 1.0  # the pusher's spread does not count
        np.testing.assert_allclose(planner.risk(spread), [0.05, 0.0])


class Refinement(unittest.TestCase):
    def test_a_velocity_moves_every_later_position(self):
        # Positions x_t = x_0 + dt * sum_{s <= t} v_s: dC/dv_s = dt * sum_{t >= s} dC/dx_t.
        grad_xy = np.zeros((1, 3, 2))
        grad_xy[0, :, 0] = [1.0, 2.0, 4.0]
        grad_xy[0, 2, 1] = -1.0
        gv = planner.velocity_gradient(grad_xy, 0.5)
        np.testing.assert_allclose(gv[0, :, 0], [3.5, 3.0, 2.0])
        np.testing.assert_allclose(gv[0, :, 1], [-0.5, -0.5, -0.5])


class Paired(unittest.TestCase):
    def test_two_records_compare_seed_by_seed(self):
        ref = {"seeds": [{"seed": k, "planned": p, "planned_off": 0.1, "seconds": 4.0} for k, p in [(0, 0.2), (1, 0.3), (2, 0.1)]]}
        cand = {"seeds": [{"seed": k, "planned": p, "planned_off": 0.05, "seconds": 5.0} for k, p in [(0, 0.1), (1, 0.2), (3, 0.9)]]}
        line = planner.paired(ref, cand)
        self.assertIn("over 2 paired seeds: 0.150 m against 0.250 m", line)
        self.assertIn("difference -0.1000 m (paired s.e. 0.0000 m", line)
        self.assertIn("closer on 2 of 2", line)
        self.assertIn("off by 0.050 m against 0.100 m", line)
        self.assertIn("planning 5.0 s a seed against 4.0 s", line)
        with self.assertRaises(ValueError):
            planner.paired(ref, {"seeds": [{"seed": 9, "planned": 0.1, "planned_off": 0.0}]})


class Seeds(unittest.TestCase):
    def test_single_ranges_and_lists(self):
        self.assertEqual(planner.parse_seeds("7"), [7])
        self.assertEqual(planner.parse_seeds("0-3"), [0, 1, 2, 3])
        self.assertEqual(planner.parse_seeds("1,4,9-11"), [1, 4, 9, 10, 11])

    def test_bad_seeds_are_refused(self):
        for text in ["", "3-1", "a", "-2", "1,,2"]:
            with self.assertRaises(ValueError, msg=text):
                planner.parse_seeds(text)

    def test_summary_counts_the_plans_closer_than_random(self):
        line = planner.summary([(0.10, 0.30, 0.05, 0.01), (0.20, 0.10, 0.02, 0.03), (0.30, 0.35, 0.11, 0.02)])
        self.assertIn("over 3 seeds", line)
        self.assertIn("planned mean 0.200 m, median 0.200 m", line)
        self.assertIn("random plan mean 0.250 m, median 0.300 m", line)
        self.assertIn("planned closer than random on 2 of 3", line)
        self.assertIn("planned paths off by mean 0.060 m (median 0.050)", line)
        self.assertIn("random paths by mean 0.020 m (median 0.020)", line)
        timed = planner.summary([(0.10, 0.30, 0.05, 0.01, 4.0), (0.20, 0.10, 0.02, 0.03, 6.0)])
        self.assertIn("planning took 5.0 s a seed (median)", timed)


class Record(unittest.TestCase):
    def test_the_record_pairs_seeds_with_their_distances_and_keeps_the_settings(self):
        args = argparse.Namespace(
            goal=[0.35, 0.15], rounds=8, horizon=10, execute=4, samples=48, iterations=2, speed=0.8,
            side_weight=0.5, server="http://x", seeds="3,5",
        )
        model = {"name": "rigidformer-small", "architecture": "rigidformer", "dt_frame": 1 / 24}
        doc = planner.record(model, args, [(3, (0.1, 0.3, 0.05, 0.01)), (5, (0.2, 0.1, 0.02, 0.03))])
        self.assertEqual(doc["model"], {"name": "rigidformer-small", "architecture": "rigidformer"})
        # Only what shapes a plan: not the transport or the seed list.
        self.assertEqual(set(doc["settings"]), set(planner.SETTINGS))
        self.assertEqual(doc["settings"]["goal"], [0.35, 0.15])
        self.assertEqual([s["seed"] for s in doc["seeds"]], [3, 5])
        self.assertEqual(doc["seeds"][1]["random_off"], 0.03)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "planner.json")
            planner.write_record(path, doc)
            planner.write_record(path, doc)  # rewritten in place, no temporary file left
            self.assertEqual(os.listdir(tmp), ["planner.json"])
            with open(path) as f:
                self.assertEqual(json.load(f), doc)


if __name__ == "__main__":
    unittest.main()
