"""The gRPC ``ModelInfo`` message as the HTTP ``ModelInfo`` document (no server needed)."""

import json
import unittest

from dynaserve.grpc import model_info
from dynaserve.v1 import world_model_pb2 as pb


class ModelInfoTest(unittest.TestCase):
    def test_an_ensemble_lists_its_members_and_a_single_network_none(self):
        config = json.dumps({"architecture": "rigidformer"})
        ensemble = pb.ModelInfo(
            name="pair", architecture="rigidformer", config_json=config, members=["a", "b"]
        )
        self.assertEqual(model_info(ensemble)["members"], ["a", "b"])
        single = pb.ModelInfo(name="one", architecture="rigidformer", config_json=config)
        # The HTTP document leaves out an empty list, and so does the client.
        self.assertNotIn("members", model_info(single))


if __name__ == "__main__":
    unittest.main()
