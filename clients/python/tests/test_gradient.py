"""The session ``gradient`` call on every client: the cost document and answer conversions (no
server needed), and, against a real server whose addresses are in DYNASERVE_HTTP and
DYNASERVE_GRPC (started by the workspace test `tests/python_client.rs`), the same call over
HTTP, gRPC and asyncio gRPC: the same answer of the documented shapes where the model computes
gradients, FAILED_PRECONDITION (400) on every client where it does not."""

import asyncio
import os
import unittest

import numpy as np

from dynaserve import Body, Client, DynaserveError, Gradients, box_points, gradient_cost
from dynaserve.gradient import cost_arg, gradients_from_doc
from dynaserve.scene import poses_array

try:
    from dynaserve.grpc import AsyncGrpcClient, GrpcClient
    from dynaserve.grpc_convert import _gradient_request, _gradients
    from dynaserve.v1 import sessions_pb2 as spb
    from dynaserve.v1 import world_model_pb2 as pb
except ImportError:  # pragma: no cover - the grpc extra is not installed
    GrpcClient = None


def pusher_paths(steps, speeds):
    """One candidate per speed: the pusher (object 1) towards the box, [steps, 7] each."""
    out = []
    for v in speeds:
        path = np.tile([-0.3, 0, 0.05, 0, 0, 0, 1.0], (steps, 1))
        path[:, 0] += v * np.arange(1, steps + 1)
        out.append({1: path})
    return out


def answer_doc():
    """A ``GradientResponse`` document: two candidates of two steps, one kinematic object,
    the final frame of a two-object scene."""
    pose = {"translation": [0.1, 0.0, 0.05], "rotation": [0.0, 0.0, 0.0, 1.0]}
    return {
        "model": "m",
        "candidates": [
            {
                "cost": 1.5 + c,
                "steps": [
                    {"kinematic": [{"translation": [c, s, 1.0], "rotation": [0.0, 0.5, s]}]} for s in range(2)
                ],
                "frames": [{"step": 2, "time": 0.08, "poses": [pose, pose]}],
            }
            for c in range(2)
        ],
        "timing": {"queue_ms": 0.0, "forward_ms": 1.0, "total_ms": 2.0},
    }


class OfflineTest(unittest.TestCase):
    def test_costs_from_tuples_and_documents_are_checked(self):
        cost = gradient_cost([(0, 0, [0.3, 0, 0.1], 1.0), (0, 4, [0, 0, 0], 0.0, [0, 0, 0, 1], 0.5)], smoothness=0.1)
        self.assertEqual(cost["targets"][0], {"object": 0, "step": 0, "position": [0.3, 0.0, 0.1], "position_weight": 1.0})
        self.assertEqual(cost["targets"][1]["rotation_weight"], 0.5)
        self.assertEqual(cost_arg(cost), cost)
        self.assertEqual(cost_arg(None), {"targets": [], "smoothness": 0.0})
        self.assertEqual(cost_arg([{"object": 2}])["targets"][0]["position"], [0.0, 0.0, 0.0])
        with self.assertRaisesRegex(ValueError, r"cost.targets\[0\].position: expected \[3\]"):
            gradient_cost([(0, 0, [1, 2], 1.0)])
        with self.assertRaisesRegex(ValueError, r"cost.targets\[0\]: unknown keys \['weight'\]"):
            gradient_cost([{"object": 0, "weight": 1.0}])
        with self.assertRaisesRegex(ValueError, "cost.smoothness: nan is not finite"):
            gradient_cost(smoothness=float("nan"))

    def test_answers_are_arrays_of_the_documented_shapes(self):
        g = gradients_from_doc(answer_doc(), poses_array)
        self.assertIsInstance(g, Gradients)
        self.assertEqual(g.cost.tolist(), [1.5, 2.5])
        self.assertEqual(g.translation.shape, (2, 2, 1, 3))
        self.assertEqual(g.rotation.shape, (2, 2, 1, 3))
        self.assertEqual(g.translation[1, 1, 0].tolist(), [1.0, 1.0, 1.0])
        self.assertEqual(g.poses.shape, (2, 1, 2, 7))
        self.assertEqual(g.steps.tolist(), [2])

    @unittest.skipIf(GrpcClient is None, "the grpc extra is not installed")
    def test_grpc_messages_read_and_write_as_the_json_documents(self):
        doc = answer_doc()
        msg = spb.GradientResponse(
            model="m",
            candidates=[
                spb.CandidateGradient(
                    cost=c["cost"],
                    steps=[
                        spb.StepGradient(
                            kinematic=[
                                spb.PoseGradient(translation=pb.Vec3(x=t[0], y=t[1], z=t[2]), rotation=pb.Vec3(x=r[0], y=r[1], z=r[2]))
                                for t, r in ((k["translation"], k["rotation"]) for k in s["kinematic"])
                            ]
                        )
                        for s in c["steps"]
                    ],
                    frames=[
                        pb.StepFrame(
                            step=2,
                            time=0.08,
                            poses=[pb.Pose(translation=pb.Vec3(x=0.1, y=0, z=0.05), rotation=pb.Quaternion(w=1)) for _ in range(2)],
                        )
                    ],
                )
                for c in doc["candidates"]
            ],
        )
        a, b = _gradients(msg), gradients_from_doc(doc, poses_array)
        for field in ("cost", "translation", "rotation", "poses", "steps"):
            np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-7, err_msg=field)
        req = _gradient_request("s", 3, pusher_paths(3, [0.05]), gradient_cost([(0, 0, [0.3, 0, 0.1], 1.0, [0, 0, 0, 1], 0.5)], 0.1), 1, 500)
        self.assertEqual((req.steps, req.every, req.timeout_ms, len(req.candidates[0].actions)), (3, 1, 500, 3))
        self.assertAlmostEqual(req.candidates[0].actions[2].kinematic[0].pose.translation.x, -0.15, places=6)
        self.assertTrue(req.cost.targets[0].HasField("rotation"))
        self.assertAlmostEqual(req.cost.smoothness, 0.1, places=6)
        with self.assertRaisesRegex(ValueError, r"kinematic\[0\]\[1\]: expected \[steps, 7\]"):
            _gradient_request("s", 3, [{1: np.zeros((3, 6))}], None, 0, 0)


LIVE = "DYNASERVE_HTTP" in os.environ and "DYNASERVE_GRPC" in os.environ and GrpcClient is not None


@unittest.skipUnless(LIVE, "needs a server (DYNASERVE_HTTP, DYNASERVE_GRPC)")
class LiveTest(unittest.TestCase):
    STEPS = 6
    COST = gradient_cost([(0, 0, [0.3, 0.0, 0.1], 1.0)], smoothness=0.1)

    @classmethod
    def setUpClass(cls):
        cls.h = Client(os.environ["DYNASERVE_HTTP"], timeout=120)
        cls.g = GrpcClient(os.environ["DYNASERVE_GRPC"], timeout=120)
        rigid = [m for m in cls.h.list_models() if m["architecture"] == "rigidformer"][0]
        cls.model = rigid["name"]
        cls.supported = rigid.get("gradients", False)
        scene = [
            Body(box_points([0.1, 0.1, 0.1], 64, 1), pose=[0, 0, 0.1, 0, 0, 0, 1]),
            Body(box_points([0.05, 0.05, 0.05], 64, 2), pose=[-0.3, 0, 0.05, 0, 0, 0, 1]),
        ]
        cls.session = cls.h.create_session(scene, kinematic=[1], model=cls.model)

    @classmethod
    def tearDownClass(cls):
        cls.session.delete()
        cls.g.close()

    def calls(self, paths):
        """The same call on the HTTP, gRPC and asyncio gRPC clients (or the error each raised)."""

        def attempt(f):
            try:
                return f()
            except DynaserveError as e:
                return e

        async def on_aio():
            async with AsyncGrpcClient(os.environ["DYNASERVE_GRPC"], timeout=120) as a:
                s = await a.session(self.session.id)
                try:
                    return await s.gradient(self.STEPS, kinematic=paths, cost=self.COST, every=1)
                except DynaserveError as e:
                    return e

        return [
            attempt(lambda: self.session.gradient(self.STEPS, kinematic=paths, cost=self.COST, every=1)),
            attempt(lambda: self.g.session(self.session.id).gradient(self.STEPS, kinematic=paths, cost=self.COST, every=1)),
            asyncio.run(on_aio()),
        ]

    def test_every_client_answers_alike(self):
        paths = pusher_paths(self.STEPS, [0.05, 0.04])
        answers = self.calls(paths)
        if not self.supported:
            for a in answers:
                self.assertIsInstance(a, DynaserveError)
                self.assertEqual((a.code, a.status), ("FAILED_PRECONDITION", 400), str(a))
            return
        first = answers[0]
        self.assertEqual(first.translation.shape, (2, self.STEPS, 1, 3))
        self.assertEqual(first.rotation.shape, (2, self.STEPS, 1, 3))
        self.assertEqual(first.poses.shape, (2, self.STEPS, 2, 7))
        self.assertEqual(first.steps.tolist(), list(range(1, self.STEPS + 1)))
        self.assertTrue(np.isfinite(first.translation).all() and np.isfinite(first.cost).all())
        for other in answers[1:]:
            np.testing.assert_allclose(other.cost, first.cost, rtol=1e-6)
            np.testing.assert_allclose(other.translation, first.translation, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(other.rotation, first.rotation, rtol=1e-5, atol=1e-6)
        # The rollout is the one Predict gives for the same paths.
        predicted = self.session.predict(self.STEPS, kinematic=paths, every=1)
        np.testing.assert_allclose(first.poses, predicted, atol=1e-3)

    def test_a_candidate_without_every_step_names_its_field(self):
        if not self.supported:
            self.skipTest("the model computes no gradients")
        short = [{1: pusher_paths(self.STEPS, [0.05])[0][1][:-1]}]
        for a in self.calls(short):
            self.assertIsInstance(a, DynaserveError)
            self.assertEqual((a.code, a.field), ("INVALID_ARGUMENT", "candidates[0].actions"))


if __name__ == "__main__":
    unittest.main()
