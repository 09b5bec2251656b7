"""``predict(..., with_spread=True)`` on hand-made Predict responses (no server needed): the
JSON document and the protobuf ``PredictResponse`` give the same ``[variants, frames, objects,
2]`` spread through every client, sync and asyncio, HTTP and gRPC, plain and session Predict."""

import asyncio
import socket
import unittest

import numpy as np

from dynaserve import AsyncClient, Body, Client, Session, pose_doc
from dynaserve.grpc import AsyncGrpcClient, AsyncGrpcSession, GrpcClient, GrpcSession, pose_pb
from dynaserve.v1 import sessions_pb2 as spb
from dynaserve.v1 import world_model_pb2 as pb

INFO = {"session_id": "00ff", "model": "m", "objects": 2, "dt_steps": 1, "kinematic": [1], "expires_at_unix_ms": 0}
# 2 variants x 3 frames x 2 objects; every value distinct so that a transposition shows.
POSES = np.array(
    [[[[0.1 * v + 0.01 * k + j, 0, 0.05, 0, 0, 0, 1] for j in range(2)] for k in range(3)] for v in range(2)]
)
SPREAD = np.array([[[[0.001 * (v + 1) * (k + 1) * (j + 1), 10.0 * v + k + 0.5 * j] for j in range(2)] for k in range(3)] for v in range(2)])


def response_doc(spread=True):
    """``POST /v1/predict``'s JSON document; without ``spread`` no frame has the key."""
    def frame(v, k):
        f = {"step": k + 1, "time": 0.1 * (k + 1), "poses": [pose_doc(p) for p in POSES[v, k]]}
        if spread:
            f["spread"] = [{"position_m": s[0], "orientation_deg": s[1]} for s in SPREAD[v, k]]
        return f

    return {"model": "m", "trajectories": [{"frames": [frame(v, k) for k in range(3)]} for v in range(2)], "timing": {}}


def response_pb(spread=True):
    """The same response as a ``PredictResponse`` message."""
    def frame(v, k):
        return pb.StepFrame(
            step=k + 1,
            time=0.1 * (k + 1),
            poses=[pose_pb(p) for p in POSES[v, k]],
            spread=[pb.ObjectSpread(position_m=s[0], orientation_deg=s[1]) for s in SPREAD[v, k]] if spread else [],
        )

    return pb.PredictResponse(model="m", trajectories=[pb.Trajectory(frames=[frame(v, k) for k in range(3)]) for v in range(2)])


def closed_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bodies():
    cube = [[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (-0.1, 0.1)]
    return [Body(cube, pose=[0.3 * j, 0, 0.1, 0, 0, 0, 1]) for j in range(2)]


class PredictSpread(unittest.TestCase):
    def check(self, out, spread=True):
        poses, got = out
        np.testing.assert_allclose(poses, POSES, atol=1e-6)
        if not spread:
            self.assertIsNone(got)
            return
        self.assertEqual(got.shape, (2, 3, 2, 2))
        self.assertEqual(got.dtype, np.float32)
        np.testing.assert_allclose(got, SPREAD, rtol=1e-6)

    def test_http_client_and_session(self):
        c = Client(f"http://127.0.0.1:{closed_port()}", timeout=5)
        for spread in (True, False):
            c.request = lambda *_a, **_k: response_doc(spread)
            s = Session(c, INFO)
            self.check(c.predict([bodies(), bodies()], steps=3, every=1, with_spread=True), spread)
            self.check(s.predict(3, poses=[{}, {}], every=1, with_spread=True), spread)
            # Without the keyword the poses array alone, as before.
            for plain in (c.predict([bodies()], steps=3), s.predict(3)):
                self.assertIsInstance(plain, np.ndarray)
                np.testing.assert_allclose(plain, POSES, atol=1e-6)

    def test_async_http_client(self):
        a = AsyncClient(f"http://127.0.0.1:{closed_port()}", timeout=5)
        a.sync.request = lambda *_a, **_k: response_doc()
        self.check(asyncio.run(a.predict([bodies()], 3, every=1, with_spread=True)))
        self.assertIsInstance(asyncio.run(a.predict([bodies()], 3)), np.ndarray)

    def test_grpc_client_and_session(self):
        g = GrpcClient(f"127.0.0.1:{closed_port()}", timeout=5)
        try:
            for spread in (True, False):
                g._unary = lambda *_a, **_k: response_pb(spread)
                s = GrpcSession(g, spb.SessionInfo(**INFO))
                self.check(g.predict([bodies(), bodies()], steps=3, every=1, with_spread=True), spread)
                self.check(s.predict(3, poses=[{}, {}], every=1, with_spread=True), spread)
                for plain in (g.predict([bodies()], steps=3), s.predict(3)):
                    self.assertIsInstance(plain, np.ndarray)
                    np.testing.assert_allclose(plain, POSES, atol=1e-6)
        finally:
            g.close()

    def test_async_grpc_client_and_session(self):
        async def calls():
            g = AsyncGrpcClient(f"127.0.0.1:{closed_port()}", timeout=5)

            async def unary(*_a, **_k):
                return response_pb()

            g._unary = unary
            s = AsyncGrpcSession(g, spb.SessionInfo(**INFO))
            try:
                return (
                    await g.predict([bodies()], steps=3, every=1, with_spread=True),
                    await s.predict(3, every=1, with_spread=True),
                    await g.predict([bodies()], steps=3),
                )
            finally:
                await g.close()

        plain_and_session = asyncio.run(calls())
        self.check(plain_and_session[0])
        self.check(plain_and_session[1])
        self.assertIsInstance(plain_and_session[2], np.ndarray)

    def test_json_and_protobuf_agree(self):
        from dynaserve.client import _trajectories as from_json
        from dynaserve.grpc_convert import _trajectories as from_pb

        for spread in (True, False):
            a, b = from_json(response_doc(spread), True), from_pb(response_pb(spread), True)
            np.testing.assert_allclose(a[0], b[0], atol=1e-6)  # the message's poses are float32
            if spread:
                np.testing.assert_array_equal(a[1], b[1])
            else:
                self.assertIsNone(a[1])
                self.assertIsNone(b[1])

    def test_frames_that_disagree_about_spread_are_refused(self):
        from dynaserve.client import _trajectories

        doc = response_doc()
        del doc["trajectories"][1]["frames"][2]["spread"]
        with self.assertRaises(ValueError) as e:
            _trajectories(doc, True)
        self.assertEqual(str(e.exception), "trajectories[1].frames[2]: no spread for 2 objects, unlike other frames")
        doc = response_doc()
        doc["trajectories"][0]["frames"][1]["spread"].pop()
        with self.assertRaises(ValueError) as e:
            _trajectories(doc, True)
        self.assertEqual(str(e.exception), "trajectories[0].frames[1]: spread of shape (1, 2) for 2 objects, unlike other frames")
        # Without the keyword the spread is not read at all.
        np.testing.assert_allclose(_trajectories(doc), POSES, atol=1e-6)


if __name__ == "__main__":
    unittest.main()
