"""``deploy.py``'s REST protocol, client side: HTTP ``POST /act`` with json-numpy bodies (OpenVLA, OpenVLA-OFT, UniVLA).

The framing, from openvla/openvla's and moojink/openvla-oft's ``vla-scripts/deploy.py``: FastAPI, one route
``POST /act``; ``json_numpy.patch()`` makes every JSON body json-numpy (an array is ``{"__numpy__": base64 of its
C-order bytes, "dtype": "<f8", "shape": [7]}``); any failure in the handler answers the JSON string ``"error"``
with HTTP 200 (its traceback stays in the server's log); a body FastAPI cannot read, HTTP 422. Our servers
(``conflictbench_serving.rest``) add ``GET /metadata`` and ``GET /healthz``. What a request and a reply hold is
the model's (its plugin's ``protocol``).

Needs the ``rest`` extra, ``conflictbench[rest]``: ``json-numpy`` (a plugin speaking the protocol requires it) and
``conflictbench-serving`` (the shared check of every array a peer sends, :mod:`conflictbench_serving.arrays`).
"""

from __future__ import annotations

import http.client
import json
import urllib.parse
from typing import Any

from ..core.errors import InfrastructureError
from .transport import HttpJsonTransport, UnreadableReply, extra_missing, refused_token

try:
    import json_numpy

    from conflictbench_serving.arrays import UnsafeArray, json_numpy_loads
except ModuleNotFoundError as missing:
    raise extra_missing(__name__, "rest", missing, install="./serving") from None

ROUTE = "/act"
METADATA_ROUTE = "/metadata"
ERROR_REPLY = "error"


class JsonNumpyTransport(HttpJsonTransport):
    """HTTP POST of json-numpy bodies to ``/act`` (a URL without a path gets it); ``"error"`` replies raise.

    On connecting it asks ``GET /metadata`` (beside ``/act``): our server says what it hosts there; upstream's
    ``deploy.py`` has no such route (404), and ``metadata`` stays empty. ``token`` goes on every request, that one
    included (a server that refuses it: :class:`PermissionError`, and the client stops the run at once).
    """

    def __init__(self, url: str, token: str | None = None, max_message_bytes: int | None = None):
        parts = urllib.parse.urlsplit(url)
        if parts.path in ("", "/"):
            parts = parts._replace(path=ROUTE)
        super().__init__(urllib.parse.urlunsplit(parts), token, max_message_bytes)
        self._metadata_path = parts.path.rsplit("/", 1)[0] + METADATA_ROUTE
        self.metadata: dict[str, Any] = {}

    def connect(self, timeout: float) -> None:
        super().connect(timeout)
        self.metadata = {}
        try:
            self._conn.request("GET", self._metadata_path, headers=self._headers)
            response = self._conn.getresponse()
            data = self.read_reply(response)
        except http.client.HTTPException as exc:
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from exc
        if response.status == 401:
            self.close()
            raise refused_token(self.url, f"HTTP 401 {data.decode(errors='replace')}")
        if response.status == 200:
            try:
                metadata = json.loads(data)
            except ValueError:
                metadata = None
            self.metadata = metadata if isinstance(metadata, dict) else {}

    def dumps(self, request: Any) -> str:
        return json_numpy.dumps(request)

    def loads(self, text: bytes) -> Any:
        try:
            reply = json_numpy_loads(text)  # each array checked before it is built (conflictbench_serving.arrays)
        except UnsafeArray as exc:  # an object, structured or void dtype, a shape that does not match the bytes
            # UnreadableReply, not a plain ValueError, which the transport reports as "not JSON", the reason lost
            raise UnreadableReply(f"a json-numpy array that cannot be read: {exc}") from None
        if isinstance(reply, str) and reply == ERROR_REPLY:
            raise InfrastructureError(
                f'{self.url} answered "error": the server caught an exception on this request (its log has the '
                "traceback; deploy.py answers every failure so, e.g. an unnorm_key the checkpoint lacks)"
            )
        return reply
