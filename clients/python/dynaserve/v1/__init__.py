"""Generated protobuf and gRPC stubs of ``proto/dynaserve/v1`` (``world_model_pb2``,
``sessions_pb2`` and their ``*_pb2_grpc`` service stubs). Do not edit: regenerate with
``clients/python/generate_stubs.py``. Needs the ``grpc`` extra (``pip install 'dynaserve[grpc]'``).
"""
