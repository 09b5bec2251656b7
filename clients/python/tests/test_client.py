"""Tests of the Python client against a real server whose HTTP address is in DYNASERVE_HTTP
(started by the workspace test `tests/python_client.rs`; it serves one RigidFormer model,
which calls naming no model reach, beside a PhysiFormer model)."""

import os
import unittest
import warnings

import numpy as np

from dynaserve import Body, Client, DynaserveError, OutOfRangeWarning, Session, box_points


def bodies():
    return [
        Body(box_points([0.1, 0.1, 0.1], 64, 1), pose=[0, 0, 0.6, 0, 0, 0, 1], velocity=[0.5, 0, 0, 0, 0, 0]),
        Body(box_points([0.05, 0.05, 0.05], 64, 2), pose=[-0.3, 0, 0.05, 0, 0, 0, 1]),
    ]


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.c = Client(os.environ["DYNASERVE_HTTP"])

    def test_rollout_session_and_predict_agree(self):
        models = self.c.list_models()
        self.assertEqual([m["architecture"] for m in models].count("rigidformer"), 1)
        frames = list(self.c.rollout(bodies(), steps=6))
        self.assertEqual([f.step for f in frames], list(range(1, 7)))
        self.assertEqual(frames[0].poses.shape, (2, 7))
        # A single network estimates no spread (an ensemble's frames carry [objects, 2]).
        self.assertIsNone(frames[0].spread)
        s = self.c.create_session(bodies())
        stepped = s.step(3) + s.step(3)
        for a, b in zip(frames, stepped):
            np.testing.assert_allclose(a.poses, b.poses, atol=1e-5)
        # Predict from a fresh fork of the start equals Predict from full scenes.
        start = self.c.create_session(bodies())
        from_session = start.predict(6, poses=[{}, {1: [-0.2, 0, 0.05, 0, 0, 0, 1]}])
        moved = bodies()
        moved[1].pose = np.array([-0.2, 0, 0.05, 0, 0, 0, 1])
        full = self.c.predict([bodies(), moved], steps=6)
        self.assertEqual(from_session.shape, (2, 1, 2, 7))
        np.testing.assert_allclose(from_session, full, atol=1e-5)
        np.testing.assert_allclose(full[0, -1], frames[-1].poses, atol=1e-5)
        # with_spread: the same poses and, from a single network, no spread.
        poses, spread = self.c.predict([bodies(), moved], steps=6, with_spread=True)
        self.assertIsNone(spread)
        np.testing.assert_allclose(poses, full, atol=1e-6)
        poses, spread = start.predict(6, poses=[{}, {1: [-0.2, 0, 0.05, 0, 0, 0, 1]}], with_spread=True)
        self.assertIsNone(spread)
        np.testing.assert_allclose(poses, from_session, atol=1e-6)

    def test_objects_outside_the_trained_ranges_warn(self):
        slippery = bodies()
        slippery[0].friction = 0.0
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            list(self.c.rollout(bodies(), steps=1))
            self.assertEqual([w for w in caught if w.category is OutOfRangeWarning], [])
            list(self.c.rollout(slippery, steps=1))
            self.c.predict([bodies(), slippery], steps=1)
        got = [str(w.message) for w in caught if w.category is OutOfRangeWarning]
        self.assertEqual(len(got), 2, got)
        self.assertTrue(got[0].startswith("scene.objects[0].friction: 0 is outside the range"), got[0])
        self.assertTrue(got[1].startswith("variants[1].objects[0].friction: 0 is outside"), got[1])

    def test_fork_set_state_kinematic_and_errors(self):
        s = self.c.create_session(bodies(), kinematic=[1])
        f = s.fork()
        self.assertNotEqual(f.id, s.id)
        path = np.tile([-0.3, 0, 0.05, 0, 0, 0, 1.0], (4, 1))
        path[:, 0] += 0.02 * np.arange(1, 5)
        frames = s.step(4, kinematic={1: path})
        np.testing.assert_allclose(frames[-1].poses[1], path[-1], atol=1e-6)
        self.assertEqual(f.state()["step"], 0)
        st = f.set_state({0: [1.0, 1.0, 0.1, 0, 0, 0, 1]})
        np.testing.assert_allclose(st["poses"][0], [1.0, 1.0, 0.1, 0, 0, 0, 1], atol=1e-6)
        with self.assertRaises(DynaserveError) as e:
            s.step(1, kinematic={0: path[:1]})
        self.assertEqual(e.exception.status, 422)
        self.assertEqual(e.exception.field, "actions[0].kinematic[0].object")
        s.delete()
        with self.assertRaises(DynaserveError) as e:
            s.state()
        self.assertEqual((e.exception.status, e.exception.code), (404, "NOT_FOUND"))

    def test_a_session_is_reattached_by_id(self):
        s = self.c.create_session(bodies(), kinematic=[1])
        s.step(2)
        # Another client (as another process would) takes the session up by its id.
        again = Client(os.environ["DYNASERVE_HTTP"]).session(s.id)
        self.assertIsInstance(again, Session)
        self.assertEqual((again.id, again.objects), (s.id, 2))
        self.assertEqual((again.model, again.dt_steps, again.kinematic), (None, None, None))
        self.assertEqual(again.state()["step"], 2)
        self.assertEqual([f.step for f in again.step(1)], [3])
        np.testing.assert_allclose(s.state()["poses"], again.state()["poses"])
        again.delete()
        for gone in (s.id, "0" * 32):
            with self.assertRaises(DynaserveError) as e:
                self.c.session(gone)
            self.assertEqual((e.exception.status, e.exception.code), (404, "NOT_FOUND"))
        # An id is one path segment, never a way to another endpoint.
        with self.assertRaises(DynaserveError):
            self.c.session("../models")


if __name__ == "__main__":
    unittest.main()
