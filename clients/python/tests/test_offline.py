"""What the client checks and does before any server answers (no server needed): argument
shapes and finite values, body-frame point clouds, documented defaults, the type hints, the
package version, and a server that cannot be reached."""

import inspect
import math
import pathlib
import re
import socket
import typing
import unittest
import warnings

import numpy as np
import numpy.typing as npt

import dynaserve
from dynaserve import Body, Client, DynaserveError, MeshObject, Session, box_points
from dynaserve.grpc import GrpcClient, GrpcSession, Interaction, action_pb, scene_pb

CUBE = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.15, 0.15) for z in (-0.15, 0.15)])
INFO = {"session_id": "00ff", "model": "m", "objects": 2, "dt_steps": 1, "kinematic": [1], "expires_at_unix_ms": 0}


def closed_port():
    """A port on 127.0.0.1 that nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bodies():
    return [
        Body(box_points([0.1, 0.1, 0.1], 64, 1), pose=[0, 0, 0.3, 0, 0, 0, 1]),
        Body(box_points([0.05, 0.05, 0.05], 64, 2), pose=[-0.3, 0, 0.05, 0, 0, 0, 1]),
    ]


def with_body(j, **changes):
    out = bodies()
    for k, v in changes.items():
        setattr(out[j], k, v)
    return out


class ArrayArguments(unittest.TestCase):
    """Every array argument is checked before anything is sent, with a message naming it; the
    same over HTTP and gRPC."""

    @classmethod
    def setUpClass(cls):
        port = closed_port()
        cls.http = Client(f"http://127.0.0.1:{port}", timeout=5)
        cls.grpc = GrpcClient(f"127.0.0.1:{port}", timeout=5)

    @classmethod
    def tearDownClass(cls):
        cls.grpc.close()

    def refused(self, message, *calls):
        for call in calls:
            with self.assertRaises(ValueError) as e:
                call()
            self.assertEqual(str(e.exception), message)

    def both(self, message, scene):
        self.refused(
            message,
            lambda: list(self.http.rollout(scene, steps=1)),
            lambda: list(self.grpc.rollout(scene, steps=1)),
            lambda: self.http.create_session(scene),
            lambda: self.grpc.create_session(scene),
        )

    def test_scene_arrays_of_the_wrong_shape(self):
        transposed = box_points([0.1] * 3, 5).T
        self.both("bodies[0].points: expected [N, 3], got shape (3, 5)", with_body(0, points=transposed))
        self.both("bodies[1].points: expected [N, 3], got shape (5, 2)", with_body(1, points=np.zeros((5, 2))))
        self.both("bodies[1].pose: expected [7], got shape (6,)", with_body(1, pose=[0, 0, 0.1, 0, 0, 1]))
        self.both("bodies[0].velocity: expected [6], got shape (3,)", with_body(0, velocity=[1, 0, 0]))
        self.refused(
            "variants[1][0].points: expected [N, 3], got shape (3, 5)",
            lambda: self.http.predict([bodies(), with_body(0, points=transposed)], steps=1),
            lambda: self.grpc.predict([bodies(), with_body(0, points=transposed)], steps=1),
        )

    def test_values_that_are_not_finite(self):
        points = box_points([0.1] * 3, 8)
        points[2, 1] = np.nan
        self.both("bodies[0].points: nan at [2, 1] is not finite", with_body(0, points=points))
        self.both("bodies[1].pose: inf at [0] is not finite", with_body(1, pose=[np.inf, 0, 0, 0, 0, 0, 1]))
        self.both("bodies[1].mass: nan is not finite", with_body(1, mass=float("nan")))
        self.both("bodies[0].friction: expected a number, got 'high'", with_body(0, friction="high"))
        # A JSON scene document with a NaN is refused here, not by the server's JSON parser.
        self.both("scene.objects[0].mass: nan is not finite", {"objects": [dict(bodies()[0].doc(), mass=math.nan)]})

    def test_session_arguments(self):
        for s in (Session(self.http, INFO), GrpcSession(self.grpc, _info_pb())):
            self.refused("kinematic[1]: expected [steps, 7], got shape (4, 6)", lambda: s.step(4, kinematic={1: np.zeros((4, 6))}))
            self.refused("kinematic[1][1]: expected [steps, 7], got shape (7,)", lambda: s.predict(1, kinematic=[{}, {1: np.zeros(7)}]))
            self.refused("poses[0]: expected [7], got shape (3,)", lambda: s.set_state({0: [0, 0, 0]}))
            self.refused(
                "velocities[0]: inf at [4] is not finite",
                lambda: s.set_state({0: [0, 0, 0, 0, 0, 0, 1]}, velocities={0: [0, 0, 0, 0, np.inf, 0]}),
            )
            self.refused("poses[1][0]: expected [7], got shape (2, 7)", lambda: s.predict(1, poses=[{}, {0: np.zeros((2, 7))}]))
        self.refused("kinematic[1]: expected [7], got shape (3,)", lambda: action_pb({1: [0, 0, 1]}))

    def test_mesh_arrays(self):
        cases = [
            ("objects[0].vertices: expected [N, 3], got shape (3, 8)", MeshObject(CUBE.T)),
            ("objects[0].faces: expected [M, 3], got shape (4,)", MeshObject(CUBE, faces=[0, 1, 2, 3])),
            ("objects[0].faces: 0.5 at [0, 1] is not a vertex index", MeshObject(CUBE, faces=[[0, 0.5, 2]])),
            ("objects[0].velocity: nan at [2] is not finite", MeshObject(CUBE, velocity=[0, 0, np.nan, 0, 0, 0])),
            ("objects[0].vertex_velocities: expected [N, 3], got shape (8, 2)", MeshObject(CUBE, vertex_velocities=np.zeros((8, 2)))),
            ("objects[0].material: 'liquid' is not one of ['elastic', 'rigid']", MeshObject(CUBE, "liquid")),
        ]
        for message, o in cases:
            self.refused(message, lambda: self.http.generate([o]), lambda: self.grpc.generate([o]))
        self.refused(
            "sampler: 'rk4' is not one of ['euler', 'heun']",
            lambda: self.http.generate([MeshObject(CUBE)], sampler="rk4"),
            lambda: self.grpc.generate([MeshObject(CUBE)], sampler="rk4"),
        )

    def test_scene_documents_over_grpc_name_their_fields(self):
        doc = bodies()[0].doc()
        del doc["mass"]
        with self.assertRaises(KeyError) as e:
            scene_pb({"objects": [bodies()[1].doc(), doc]})
        self.assertIn("scene.objects[1].mass: required", str(e.exception))
        doc = dict(bodies()[0].doc(), points=[[0, 0, 0, 1]])
        self.refused("scene.objects[0].points: expected [N, 3], got shape (1, 4)", lambda: scene_pb({"objects": [doc]}))


def _info_pb():
    from dynaserve.v1 import sessions_pb2

    return sessions_pb2.SessionInfo(**INFO)


class BodyFrame(unittest.TestCase):
    def test_world_frame_points_warn_and_from_world_points_centres_them(self):
        cloud = box_points([0.1, 0.05, 0.02], 200, 3) + [0.4, -0.2, 0.02]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            Body(cloud)
            Body(box_points([0.1] * 3, 64, 1))  # body frame: no warning
            Body(box_points([0.004] * 3, 64) + [0.006, 0, 0])  # off by 6 mm only: no warning
            b = Body.from_world_points(cloud, mass=2.0, velocity=[1, 0, 0, 0, 0, 0])
        self.assertEqual(len(caught), 1, [str(w.message) for w in caught])
        self.assertTrue(issubclass(caught[0].category, dynaserve.BodyFrameWarning))
        self.assertTrue(issubclass(dynaserve.BodyFrameWarning, UserWarning))
        self.assertIn("Body.from_world_points", str(caught[0].message))
        centroid = cloud.mean(axis=0)
        np.testing.assert_allclose(b.pose, np.r_[centroid, 0, 0, 0, 1])
        np.testing.assert_allclose(b.points, cloud - centroid)
        np.testing.assert_allclose(np.asarray(b.points) + b.pose[:3], cloud)
        self.assertEqual((b.mass, b.friction, b.restitution), (2.0, 0.5, 0.2))
        np.testing.assert_allclose(b.velocity, [1, 0, 0, 0, 0, 0])
        with self.assertRaises(ValueError) as e:
            Body.from_world_points(cloud.T)
        self.assertEqual(str(e.exception), "points: expected [N, 3], got shape (3, 200)")


def _takes_array_like(hint):
    if set(typing.get_args(npt.ArrayLike)) <= set(typing.get_args(hint)):
        return True
    return any(_takes_array_like(a) for a in typing.get_args(hint))


def _entries(doc):
    """The ``name: text`` entries of a docstring's Args or Attributes section."""
    return {m.group(1): m.group(2) for m in re.finditer(r"^ +(\w+): (.*(?:\n(?! +\w+: ).*)*)", doc, re.M)}


class Documentation(unittest.TestCase):
    def test_array_arguments_are_annotated_array_like(self):
        hints = [
            (Body, ["points", "pose", "velocity"]),
            (MeshObject, ["vertices", "faces", "velocity", "vertex_velocities"]),
            (Session.step, ["kinematic"]),
            (Session.set_state, ["poses", "velocities"]),
            (Session.predict, ["kinematic", "poses"]),
            (GrpcSession.step, ["kinematic"]),
            (GrpcSession.predict, ["kinematic", "poses"]),
            (Session.gradient, ["kinematic"]),
            (GrpcSession.gradient, ["kinematic"]),
            (Interaction.step, ["kinematic", "correct", "velocities"]),
            (Body.from_world_points, ["points"]),
        ]
        for owner, names in hints:
            got = typing.get_type_hints(owner)
            for name in names:
                self.assertTrue(_takes_array_like(got[name]), f"{owner.__qualname__}.{name}: {got[name]}")

    def test_every_default_is_documented(self):
        documented = [(cls, cls) for cls in (Body, MeshObject, Client)]
        documented += [(getattr(cls, m), getattr(cls, m)) for cls in (Client, Session) for m in dir(cls) if not m.startswith("_")]
        for doc_of, f in documented:
            if not callable(f):
                continue
            entries = _entries(doc_of.__doc__ or "")
            for name, p in inspect.signature(f).parameters.items():
                if p.default is not inspect.Parameter.empty:
                    self.assertIn(name, entries, f"{f.__qualname__}: {name} is not documented")
                    self.assertIn("default", entries[name].lower(), f"{f.__qualname__}: the default of {name}")

    def test_version_is_the_pyproject_one(self):
        pyproject = (pathlib.Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
        self.assertEqual(dynaserve.__version__, re.search(r'^version = "(.+)"', pyproject, re.M).group(1))


class Unreachable(unittest.TestCase):
    def test_a_closed_port_is_unavailable_over_both_transports(self):
        port = closed_port()
        c = Client(f"http://127.0.0.1:{port}", timeout=5)
        g = GrpcClient(f"127.0.0.1:{port}", timeout=5)
        for call in (c.list_models, lambda: list(c.rollout(bodies(), steps=1)), g.list_models):
            with self.assertRaises(DynaserveError) as e:
                call()
            self.assertEqual((e.exception.status, e.exception.code), (503, "UNAVAILABLE"))
            self.assertIn(f"127.0.0.1:{port}", e.exception.message)
        g.close()


if __name__ == "__main__":
    unittest.main()
