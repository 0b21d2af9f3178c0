"""`mogo serve`: many characters streaming at once over WebSocket, a viewer, clips over HTTP.

Needs the serve extra (`pip install 'mogo-edge[serve]'`: aiohttp, onnx); the base runtime does
not import this package. The protocol: mogo.serve.protocol and docs/serve.md.
"""
