"""Tests of the gRPC transport against a real server whose gRPC and HTTP addresses are in
DYNASERVE_GRPC and DYNASERVE_HTTP (started by the workspace test `tests/python_client.rs` with
a RigidFormer and a PhysiFormer model). Each answer is checked against the same request over
the other transport or the other call that must agree with it."""

import asyncio
import json
import os
import pathlib
import unittest
import warnings

import numpy as np

from dynaserve import Body, Client, DynaserveError, OutOfRangeWarning, box_points
from dynaserve.grpc import AsyncGrpcClient, GrpcClient, GrpcSession
from dynaserve.mesh import MeshObject


def bodies():
    """A falling, moving box and a small box on the floor that serves as the pusher."""
    return [
        Body(box_points([0.1, 0.1, 0.1], 64, 1), pose=[0, 0, 0.3, 0, 0, 0, 1], velocity=[0.5, 0, 0, 0, 0, 0]),
        Body(box_points([0.05, 0.05, 0.05], 64, 2), pose=[-0.3, 0, 0.05, 0, 0, 0, 1]),
    ]


def pusher_path(steps):
    """The pusher's poses at the end of each step: towards the box at 2 cm per step, [steps, 7]."""
    path = np.tile([-0.3, 0, 0.05, 0, 0, 0, 1.0], (steps, 1))
    path[:, 0] += 0.02 * np.arange(1, steps + 1)
    return path


SCENES = pathlib.Path(__file__).resolve().parents[3] / "examples" / "scenes"

CUBE = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.15, 0.15) for z in (-0.15, 0.15)])


def mesh_scene():
    """A rigid cube low in the box and an elastic one thrown at it."""
    return [
        MeshObject(CUBE + [0, 0, -0.5], "rigid"),
        MeshObject(CUBE + [0, 0, 0.2], "elastic", velocity=[1, 0, -1, 0, 0, 0]),
    ]


def assert_frames_equal(test, a, b, atol=1e-6):
    test.assertEqual([f.step for f in a], [f.step for f in b])
    for x, y in zip(a, b):
        np.testing.assert_allclose(x.poses, y.poses, atol=atol)
        test.assertAlmostEqual(x.time, y.time, places=6)


class GrpcTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.g = GrpcClient(os.environ["DYNASERVE_GRPC"], timeout=60, stream_timeout=120, step_timeout=60)
        cls.h = Client(os.environ["DYNASERVE_HTTP"], timeout=60)

    @classmethod
    def tearDownClass(cls):
        cls.g.close()

    def test_list_models_equals_http(self):
        models = self.g.list_models()
        self.assertEqual(models, self.h.list_models())
        self.assertEqual(sorted(m["architecture"] for m in models), ["physiformer", "rigidformer"])

    def test_rollout_and_predict_equal_http(self):
        frames = list(self.g.rollout(bodies(), steps=6))
        self.assertEqual([f.step for f in frames], list(range(1, 7)))
        self.assertEqual(frames[0].poses.shape, (2, 7))
        assert_frames_equal(self, frames, list(self.h.rollout(bodies(), steps=6)))
        # The box falls: the rollout is not a copy of the start.
        self.assertLess(frames[-1].poses[0, 2], 0.3 - 1e-3)
        moved = bodies()
        moved[1].pose = np.array([-0.2, 0, 0.05, 0, 0, 0, 1])
        p = self.g.predict([bodies(), moved], steps=6, every=2)
        self.assertEqual(p.shape, (2, 3, 2, 7))
        np.testing.assert_allclose(p, self.h.predict([bodies(), moved], steps=6, every=2), atol=1e-6)
        np.testing.assert_allclose(p[0, -1], frames[-1].poses, atol=1e-6)
        # with_spread: the same poses and, from a single network, no spread.
        poses, spread = self.g.predict([bodies(), moved], steps=6, every=2, with_spread=True)
        self.assertIsNone(spread)
        np.testing.assert_allclose(poses, p, atol=1e-6)
        # A scene file's JSON document (meshes sampled by the server) goes over gRPC as well.
        with open(SCENES / "collision.json") as f:
            doc = json.load(f)["scene"]
        frames = list(self.g.rollout(doc, steps=4))
        self.assertEqual(frames[0].poses.shape, (len(doc["objects"]), 7))
        assert_frames_equal(self, frames, list(self.h.rollout(doc, steps=4)))
        self.assertGreater(np.abs(frames[-1].poses[0, :3] - doc["objects"][0]["pose"]["translation"]).max(), 0.1)

    def test_objects_outside_the_trained_ranges_warn_as_over_http(self):
        bouncy = bodies()
        bouncy[1].restitution = 0.99
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            list(self.g.rollout(bodies(), steps=1))
            self.assertEqual([w for w in caught if w.category is OutOfRangeWarning], [])
            list(self.g.rollout(bouncy, steps=1))
            self.g.predict([bouncy], steps=1)
            self.g.create_session(bouncy).delete()
            with self.g.interact(bouncy) as loop:
                loop.step()
            list(self.h.rollout(bouncy, steps=1))
        got = [str(w.message) for w in caught if w.category is OutOfRangeWarning]
        self.assertEqual(len(got), 5, got)
        self.assertTrue(got[0].startswith("scene.objects[1].restitution: 0.99 is outside"), got[0])
        self.assertTrue(got[1].startswith("variants[0].objects[1].restitution"), got[1])
        self.assertEqual(got[2], got[0])
        self.assertEqual(got[3], got[0])
        self.assertEqual(got[4], got[0])

    def test_session_fork_step_state_predict_delete(self):
        s = self.g.create_session(bodies(), kinematic=[1])
        self.assertEqual((s.objects, s.dt_steps, s.kinematic), (2, 1, [1]))
        f = s.fork()
        self.assertNotEqual(f.id, s.id)
        path = pusher_path(4)
        # The session's Predict from its start equals stepping it (and leaves it in place).
        predicted = s.predict(4, kinematic=[{1: path}], every=1)
        poses, spread = s.predict(4, kinematic=[{1: path}], every=1, with_spread=True)
        self.assertIsNone(spread)
        np.testing.assert_allclose(poses, predicted, atol=1e-6)
        self.assertEqual(s.state()["step"], 0)
        frames = s.step(4, kinematic={1: path})
        self.assertEqual([x.step for x in frames], [1, 2, 3, 4])
        np.testing.assert_allclose(frames[-1].poses[1], path[-1], atol=1e-6)
        np.testing.assert_allclose(predicted[0], np.stack([x.poses for x in frames]), atol=1e-6)
        # The fork kept the start; stepped the same way it reaches the same state.
        self.assertEqual(f.state()["step"], 0)
        assert_frames_equal(self, f.step(2, kinematic={1: path[:2]}) + f.step(2, kinematic={1: path[2:]}), frames)
        st = f.state()
        self.assertEqual(st["step"], 4)
        np.testing.assert_allclose(st["poses"], frames[-1].poses, atol=1e-6)
        new = f.set_state({0: [0.5, 0.5, 0.1, 0, 0, 0, 1]})
        np.testing.assert_allclose(new["poses"][0], [0.5, 0.5, 0.1, 0, 0, 0, 1], atol=1e-6)
        # The HTTP API sees the same session store.
        np.testing.assert_allclose(self.h.request("GET", f"/v1/sessions/{f.id}")["poses"][0]["translation"], [0.5, 0.5, 0.1], atol=1e-6)
        f.delete()
        s.delete()
        with self.assertRaises(DynaserveError) as e:
            s.state()
        self.assertEqual((e.exception.status, e.exception.code), (404, "NOT_FOUND"))

    def test_interact_with_a_pusher_equals_session_step(self):
        path = pusher_path(5)
        s = self.g.create_session(bodies(), kinematic=[1])
        named = s.fork()
        stepped = s.step(5, kinematic={1: path})
        # A loop on a new session made from the scene.
        with self.g.interact(bodies(), kinematic=[1]) as loop:
            self.assertEqual(loop.model, s.model)
            created = loop.session_id
            looped = [loop.step({1: p}) for p in path]
        assert_frames_equal(self, looped, stepped)
        # The stream's own session ended with the stream.
        with self.assertRaises(DynaserveError) as e:
            self.h.request("GET", f"/v1/sessions/{created}")
        self.assertEqual(e.exception.code, "NOT_FOUND")
        # A loop on an existing session leaves it where the loop took it.
        with named.interact() as loop:
            self.assertEqual(loop.session_id, named.id)
            looped = [loop.step({1: p}) for p in path[:3]]
        self.assertEqual(named.state()["step"], 3)
        with named.interact() as loop:
            looped += [loop.step({1: p}) for p in path[3:]]
        assert_frames_equal(self, looped, stepped)
        np.testing.assert_allclose(named.state()["poses"], stepped[-1].poses, atol=1e-6)
        # A correction before a step equals SetState then Step.
        with named.interact() as loop:
            corrected = loop.step({1: path[-1]}, correct={0: [0.1, 0, 0.3, 0, 0, 0, 1]})
        s.set_state({0: [0.1, 0, 0.3, 0, 0, 0, 1]})
        assert_frames_equal(self, [corrected], s.step(1, kinematic={1: path[-1:]}))
        s.delete()
        named.delete()

    def test_interact_errors_name_the_field_and_close_the_loop(self):
        loop = self.g.interact(bodies(), kinematic=[1])
        loop.step({1: pusher_path(1)[0]})
        with self.assertRaises(DynaserveError) as e:
            loop.step({0: [0, 0, 0.3, 0, 0, 0, 1]})
        self.assertEqual((e.exception.status, e.exception.code), (422, "INVALID_ARGUMENT"))
        self.assertEqual(e.exception.field, "action.kinematic[0].object")
        with self.assertRaises(DynaserveError) as e:
            loop.step()
        self.assertEqual(e.exception.code, "CANCELLED")
        with self.assertRaises(DynaserveError) as e:
            self.g.interact(session_id="0" * 32)
        self.assertEqual((e.exception.status, e.exception.code, e.exception.field), (404, "NOT_FOUND", "session_id"))
        with self.assertRaises(ValueError):
            self.g.interact()

    def test_generate_takes_per_vertex_velocities(self):
        objs = mesh_scene()
        per_vertex = [objs[0], MeshObject(objs[1].vertices, "elastic", vertex_velocities=np.tile([1.0, 0.0, -1.0], (8, 1)))]
        a = self.g.generate(objs, frames=6, denoise_steps=2, seed=3)
        b = self.g.generate(per_vertex, frames=6, denoise_steps=2, seed=3)
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-5)
        with self.assertRaises(ValueError):
            self.g.generate([MeshObject(CUBE, "rigid", vertex_velocities=np.zeros((8, 2)))])
        with self.assertRaises(DynaserveError) as e:
            self.g.generate([MeshObject(CUBE, "rigid", vertex_velocities=np.zeros((7, 3)))])
        self.assertEqual(e.exception.field, "scene.objects[0].vertex_velocities")

    def test_generate_equals_http_and_repeats_with_its_seed(self):
        seen = []
        g = self.g.generate(mesh_scene(), frames=6, denoise_steps=2, samples=2, seed=7, on_progress=seen.append)
        self.assertEqual(g.vertices.shape, (2, 6, 16, 3))
        self.assertEqual(list(g.offsets), [0, 8, 16])
        self.assertEqual(g.object_vertices(1).shape, (2, 6, 8, 3))
        self.assertEqual(g.model, "physiformer-small")
        self.assertEqual([p["step"] for p in seen], [1, 2])
        self.assertEqual([p["t"] for p in g.progress], [0.5, 1.0])
        self.assertEqual(list(g.seeds), [7, 8])
        np.testing.assert_allclose(g.times, np.arange(6) / 48, atol=1e-9)
        # Frame 0 is the given state; the rigid cube has a fitted pose, the elastic one none.
        start = np.concatenate([o.vertices for o in mesh_scene()])
        np.testing.assert_allclose(g.vertices[:, 0], np.broadcast_to(start, (2, 16, 3)), atol=1e-5)
        np.testing.assert_allclose(g.poses[:, 0, 0], np.broadcast_to([0, 0, -0.5, 0, 0, 0, 1], (2, 7)), atol=1e-5)
        self.assertTrue(np.isfinite(g.poses[:, :, 0]).all() and np.isnan(g.poses[:, :, 1]).all())
        self.assertTrue(np.isfinite(g.fit_rms[:, :, 0]).all() and np.isnan(g.fit_rms[:, :, 1]).all())
        # Two seeds, two trajectories; the same seed again, the same trajectories (to float
        # rounding: the two samples may or may not share a forward pass).
        self.assertGreater(np.abs(g.vertices[0, 1:] - g.vertices[1, 1:]).max(), 1e-4)
        again = self.g.generate(mesh_scene(), frames=6, denoise_steps=2, samples=2, seed=7)
        np.testing.assert_allclose(again.vertices, g.vertices, atol=1e-5)
        other = self.g.generate(mesh_scene(), frames=6, denoise_steps=2, samples=1, seed=9)
        self.assertGreater(np.abs(other.vertices[0, 1:] - g.vertices[0, 1:]).max(), 1e-4)
        # The HTTP API answers the same request with the same samples.
        doc = {
            "scene": {
                "objects": [
                    {"vertices": (CUBE + [0, 0, -0.5]).tolist(), "material": "rigid"},
                    {
                        "vertices": (CUBE + [0, 0, 0.2]).tolist(),
                        "material": "elastic",
                        "velocity": {"linear": [1, 0, -1], "angular": [0, 0, 0]},
                    },
                ]
            },
            "frames": 6,
            "denoise_steps": 2,
            "samples": 2,
            "seed": 7,
        }
        http = self.h.request("POST", "/v1/generate", doc)
        over_http = np.array(
            [[np.concatenate([o["vertices"] for o in f["objects"]]) for f in s["frames"]] for s in http["samples"]]
        )
        np.testing.assert_allclose(g.vertices, over_http, atol=1e-5)
        # The rigid cube keeps its shape; with raw_vertices it is the network's own vertices,
        # as far from rigid as the fit residual says.
        def spread(v):
            return np.linalg.norm(v[..., :, None, :] - v[..., None, :, :], axis=-1)

        cube = g.object_vertices(0)
        np.testing.assert_allclose(spread(cube), np.broadcast_to(spread(cube[0, 0]), spread(cube).shape), atol=1e-4)
        raw = self.g.generate(mesh_scene(), frames=6, denoise_steps=2, samples=2, seed=7, raw_vertices=True)
        np.testing.assert_allclose(raw.fit_rms, g.fit_rms, atol=1e-5)
        moved = np.sqrt(((raw.object_vertices(0) - cube) ** 2).sum(-1).mean(-1))
        np.testing.assert_allclose(moved, raw.fit_rms[:, :, 0], atol=1e-4)
        np.testing.assert_allclose(raw.object_vertices(1), g.object_vertices(1), atol=1e-5)

    def test_http_generate_equals_grpc(self):
        seen = []
        h = self.h.generate(mesh_scene(), frames=6, denoise_steps=2, samples=2, seed=7, on_progress=seen.append)
        g = self.g.generate(mesh_scene(), frames=6, denoise_steps=2, samples=2, seed=7)
        self.assertEqual(h.vertices.shape, (2, 6, 16, 3))
        for key in ("vertices", "poses", "fit_rms", "times"):
            np.testing.assert_allclose(getattr(h, key), getattr(g, key), atol=1e-5, err_msg=key)
        self.assertEqual((list(h.offsets), list(h.seeds), h.model), (list(g.offsets), [7, 8], g.model))
        self.assertTrue(h.request_id)
        self.assertEqual([p["step"] for p in seen], [1, 2])
        self.assertEqual([p["t"] for p in h.progress], [0.5, 1.0])
        self.assertEqual(seen, h.progress)
        # Per-vertex velocities and raw vertices too.
        objs = mesh_scene()
        objs[1].vertex_velocities, objs[1].velocity = np.tile([1.0, 0.0, -1.0], (8, 1)), None
        a = self.h.generate(objs, frames=4, denoise_steps=2, seed=3, raw_vertices=True)
        b = self.g.generate(objs, frames=4, denoise_steps=2, seed=3, raw_vertices=True)
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-5)
        with self.assertRaises(DynaserveError) as e:
            self.h.generate([MeshObject(CUBE * 20, "rigid")], frames=4, denoise_steps=1)
        self.assertEqual((e.exception.status, e.exception.code), (422, "INVALID_ARGUMENT"))
        self.assertTrue(e.exception.field.startswith("scene.objects[0].vertices"), e.exception.field)

    def test_a_session_is_reattached_by_id(self):
        s = self.g.create_session(bodies(), kinematic=[1])
        s.step(2, kinematic={1: pusher_path(2)})
        again = self.g.session(s.id)
        self.assertIsInstance(again, GrpcSession)
        self.assertEqual((again.id, again.objects), (s.id, 2))
        self.assertEqual((again.model, again.dt_steps, again.kinematic), (None, None, None))
        with again.interact() as loop:
            frame = loop.step({1: pusher_path(3)[-1]})
        self.assertEqual(frame.step, 3)
        np.testing.assert_allclose(s.state()["poses"], frame.poses, atol=1e-6)
        # A session made over HTTP, taken up over gRPC.
        h = self.h.create_session(bodies())
        np.testing.assert_allclose(self.g.session(h.id).state()["poses"], h.state()["poses"], atol=1e-6)
        h.delete()
        again.delete()
        for gone in (s.id, h.id):
            with self.assertRaises(DynaserveError) as e:
                self.g.session(gone)
            self.assertEqual((e.exception.status, e.exception.code), (404, "NOT_FOUND"))

    def test_errors_carry_status_code_and_field(self):
        bad = bodies()
        bad[0].pose = np.array([0, 0, 0.3, 0, 0, 0, 2.0])
        with self.assertRaises(DynaserveError) as e:
            list(self.g.rollout(bad, steps=3))
        self.assertEqual((e.exception.status, e.exception.code), (422, "INVALID_ARGUMENT"))
        self.assertEqual(e.exception.field, "scene.objects[0].pose.rotation")
        self.assertTrue(e.exception.message.startswith("scene.objects[0].pose.rotation: "), e.exception.message)
        with self.assertRaises(DynaserveError) as e:
            self.g.predict([bodies()], steps=0)
        self.assertEqual((e.exception.code, e.exception.field), ("INVALID_ARGUMENT", "steps"))
        with self.assertRaises(DynaserveError) as e:
            self.g.generate([MeshObject(CUBE * 20, "rigid")], frames=4, denoise_steps=1)
        self.assertEqual(e.exception.code, "INVALID_ARGUMENT")
        self.assertTrue(e.exception.field.startswith("scene.objects[0].vertices"), e.exception.field)
        with self.assertRaises(ValueError):
            self.g.generate([MeshObject(CUBE, "liquid")])

    def test_deadline_and_cancel(self):
        # A deadline far shorter than a long rollout ends it with DEADLINE_EXCEEDED.
        with self.assertRaises(DynaserveError) as e:
            list(self.g.rollout(bodies(), steps=200, timeout=0.001))
        self.assertEqual((e.exception.status, e.exception.code), (504, "DEADLINE_EXCEEDED"))
        # A cancelled rollout stops yielding, quietly.
        stream = self.g.rollout(bodies(), steps=200)
        self.assertEqual([next(stream).step, next(stream).step], [1, 2])
        stream.cancel()
        self.assertEqual(list(stream), [])
        # While one loop holds a session, another caller's step cannot run: its own deadline
        # ends the wait (the loop's step_timeout, a Step's timeout), and the holder goes on.
        s = self.g.create_session(bodies(), kinematic=[1])
        with s.interact() as held:
            held.step()
            impatient = GrpcClient(os.environ["DYNASERVE_GRPC"], step_timeout=0.5)
            waiting = impatient.interact(session_id=s.id)
            with self.assertRaises(DynaserveError) as e:
                waiting.step()
            self.assertEqual((e.exception.status, e.exception.code), (504, "DEADLINE_EXCEEDED"))
            with self.assertRaises(DynaserveError) as e:
                s.step(1, timeout=0.5)
            self.assertEqual(e.exception.code, "DEADLINE_EXCEEDED")
            self.assertEqual(held.step().step, 2)
            impatient.close()
        self.assertEqual(s.state()["step"], 2)
        s.delete()

    def test_async_client_equals_the_blocking_one(self):
        path = pusher_path(3)
        target = os.environ["DYNASERVE_GRPC"]

        async def run():
            async with AsyncGrpcClient(target, timeout=60, stream_timeout=120, step_timeout=60) as a:
                models = await a.list_models()
                frames = [f async for f in a.rollout(bodies(), steps=4)]
                predicted = await a.predict([bodies()], steps=4, every=1, with_spread=True)
                s = await a.create_session(bodies(), kinematic=[1])
                f = await s.fork()
                stepped = await s.step(3, kinematic={1: path})
                async with await f.interact() as loop:
                    looped = [await loop.step({1: p}) for p in path]
                state = await f.state()
                self.assertEqual((await (await a.session(f.id)).state())["step"], state["step"])
                with self.assertRaises(DynaserveError) as e:
                    async with await a.interact(bodies(), kinematic=[1]) as bad:
                        await bad.step({0: path[0]})
                await s.delete()
                await f.delete()
                g = await a.generate(mesh_scene(), frames=4, denoise_steps=2, seed=3)
                return models, frames, predicted, stepped, looped, state, e.exception, g

        models, frames, (predicted, spread), stepped, looped, state, err, g = asyncio.run(run())
        self.assertEqual(models, self.g.list_models())
        assert_frames_equal(self, frames, list(self.g.rollout(bodies(), steps=4)))
        self.assertIsNone(spread)
        np.testing.assert_allclose(predicted[0], np.stack([x.poses for x in frames]), atol=1e-6)
        assert_frames_equal(self, looped, stepped)
        self.assertEqual(state["step"], 3)
        self.assertEqual((err.code, err.field), ("INVALID_ARGUMENT", "action.kinematic[0].object"))
        blocking = self.g.generate(mesh_scene(), frames=4, denoise_steps=2, seed=3)
        np.testing.assert_allclose(g.vertices, blocking.vertices, atol=1e-5)


if __name__ == "__main__":
    unittest.main()
