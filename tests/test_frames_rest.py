"""deploy.py's REST protocol (json-numpy): arrays a peer sends are checked before they are built, server side
(OpenVLA's and UniVLA's request parsers) and client side (the run's transport reading a reply)."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from conflictbench.hosting.rest import JsonNumpyTransport
from conflictbench.hosting.transport import UnreadableReply

IMAGE = np.zeros((8, 8, 3), np.uint8)
# A structured array (its bytes could hide anything) and one whose shape asks for more bytes than it carries.
STRUCTURED = {"__numpy__": base64.b64encode(b"\x41" * 16).decode(), "dtype": [["a", "<f8"]], "shape": [2]}
SHORT = {"__numpy__": base64.b64encode(b"\x41" * 16).decode(), "dtype": "<f8", "shape": [3]}


def _image() -> dict:
    return {"__numpy__": base64.b64encode(IMAGE.tobytes()).decode(), "dtype": "|u1", "shape": [8, 8, 3]}


@pytest.mark.parametrize("array", [STRUCTURED, SHORT], ids=["structured", "short"])
@pytest.mark.parametrize("plugin", ["openvla", "univla"])
def test_the_rest_servers_refuse_an_unsafe_array_anywhere_in_the_body(plugin, array):
    server = pytest.importorskip(f"conflictbench_{plugin}.server")
    from conflictbench_serving.rest import InvalidRequest

    body = {"image": _image(), "instruction": "go", "history": "", "unnorm_key": "libero_goal", "extra": array}
    with pytest.raises(InvalidRequest, match="not a json-numpy body: .*(refused|needs 24 bytes)") as refused:
        server.request_row(json.dumps(body).encode())
    assert "\n" not in str(refused.value)


@pytest.mark.parametrize("array", [STRUCTURED, SHORT], ids=["structured", "short"])
def test_the_rest_client_refuses_an_unsafe_array_in_a_reply(array):
    with pytest.raises(UnreadableReply, match="a json-numpy array that cannot be read: .*(refused|needs 24 bytes)"):
        JsonNumpyTransport("http://127.0.0.1:1").loads(json.dumps([array]).encode())
