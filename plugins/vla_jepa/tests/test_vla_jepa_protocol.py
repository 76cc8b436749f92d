"""VLA-JEPA's request and reply as its LIBERO client and starVLA's server lay them out (openpi-client's codec)."""

from __future__ import annotations

import numpy as np
import pytest
from openpi_client import msgpack_numpy

from conflictbench_vla_jepa.protocol import NOISE_SEED, ReplyError, infer_request, normalized_actions, packb, unpackb


def test_an_infer_request_reads_back_through_openpi_clients_codec_as_upstreams_client_sends_it():
    images = [np.full((224, 224, 3), value, np.uint8) for value in (3, 5)]
    state = np.arange(8, dtype=np.float64)
    request = infer_request(images, "open the drawer", state, request_id="ep/4", unnorm_key=None, seed=99)
    sent = msgpack_numpy.unpackb(packb(request))
    assert sent["type"] == "infer" and sent["request_id"] == "ep/4"
    payload = sent["payload"]
    assert [img[0, 0, 0] for img in payload["batch_images"][0]] == [3, 5]  # one row: agentview, then wrist
    assert payload["instructions"] == ["open the drawer"]
    assert len(payload["state"]) == 1 and payload["state"][0].shape == (1, 8)  # [state[None]], as upstream
    assert (payload["unnorm_key"], payload["do_sample"], payload["use_ddim"], payload["num_ddim_steps"]) == (
        None, False, True, 10,
    )  # fmt: skip
    assert payload[NOISE_SEED] == 99


def test_a_reply_gives_the_first_rows_chunk_and_an_in_frame_error_is_a_reply_error():
    chunk = np.arange(2 * 8 * 7, dtype=np.float32).reshape(2, 8, 7)
    reply = unpackb(msgpack_numpy.Packer().pack({"status": "ok", "ok": True, "data": {"normalized_actions": chunk}}))
    np.testing.assert_array_equal(normalized_actions(reply), chunk[0])
    with pytest.raises(ReplyError, match="boom"):
        normalized_actions({"status": "error", "ok": False, "error": {"message": "boom"}})
    with pytest.raises(ValueError, match="expected \\(B, chunk, D\\)"):
        normalized_actions({"status": "ok", "data": {"normalized_actions": np.zeros((8, 7))}})
