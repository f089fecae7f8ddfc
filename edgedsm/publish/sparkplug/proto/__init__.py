"""The official Sparkplug B payload schema, vendored, and its generated Python module.

``sparkplug_b.proto`` is copied unchanged from the Eclipse Tahu repository
(``sparkplug_b/sparkplug_b.proto``, commit 46f25e79f34234e6145d11108660dfd9133ae50d; EPL-2.0).
``sparkplug_b_pb2.py`` is generated from it; do not edit it. To regenerate (the generated code
checks the ``protobuf`` runtime: ``protoc`` 35.x writes code for protobuf 7.35+, hence the pin
``protobuf>=7.35.1,<8`` in pyproject.toml), from this directory::

    python -m pip install grpcio-tools==1.85.1   # bundles protoc 35.1; a throwaway venv is fine
    python -m grpc_tools.protoc --proto_path=. --python_out=. sparkplug_b.proto
"""
