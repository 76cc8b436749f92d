"""A VLA-JEPA policy server behaving as upstream's (starVLA's ``websocket_policy_server.py``), hosting a numpy stand-in.

Upstream's server is not installable here (no package carries it), so this one restates its behaviour from
the source, with openpi-client's own msgpack-numpy codec (not ours: the client is checked against the format):
the metadata frame ``{"env": "simpler_env"}`` first; ``{"type", "request_id", "payload"}`` requests routed by
``type`` (``ping``, ``infer``; a missing ``type`` is ``infer``); the payload passed to the model as keyword
arguments; a failure it catches answered in-frame with ``"status": "error"``; one it does not (``--crash-on``)
as a text frame and close code 1011. The stand-in's normalized chunk is a fixed function of every payload field
(:func:`normalized_for`), so a test can tell that each arrived intact.

    python starvla_standin_server.py PORT [--chunk 8] [--fail-on TEXT] [--crash-on TEXT] [--die-on TEXT]
"""

from __future__ import annotations

import argparse
import asyncio
import os

import numpy as np
import websockets.asyncio.server
import websockets.frames
from openpi_client import msgpack_numpy


def normalized_for(payload: dict, chunk: int) -> np.ndarray:
    """(1, chunk, 7): rows grow with the step; columns follow the images' orientation, state, text and seed;
    the gripper column alternates below and above 0.5."""
    image, wrist = (np.asarray(img, dtype=np.float64) for img in payload["batch_images"][0])
    state = np.asarray(payload["state"][0], dtype=np.float64)[0]
    seed = payload.get("conflictbench/noise_seed", 0)
    features = np.array(
        [
            (image[:112].mean() - image[112:].mean()) / 255.0,
            (wrist[:, :112].mean() - wrist[:, 112:].mean()) / 255.0,
            state[0] + state[5],
            (state[6] - state[7]) * 10.0,
            len(payload["instructions"][0]) / 100.0,
            (seed % 1000) / 1000.0,
        ]
    )
    rows = [np.append(features * (0.1 * (t + 1)), (0.2, 0.9)[t % 2]) for t in range(chunk)]
    return np.array(rows, dtype=np.float32)[None]


class StandInModel:
    def __init__(self, chunk: int, fail_on: str | None, crash_on: str | None, die_on: str | None):
        self.chunk, self.fail_on, self.crash_on, self.die_on = chunk, fail_on, crash_on, die_on

    def predict_action(self, batch_images, instructions, state=None, **kwargs) -> dict:
        text = instructions[0]
        if self.die_on and self.die_on in text:
            os._exit(9)
        if self.fail_on and self.fail_on in text:
            raise RuntimeError("the model failed on purpose")
        payload = {"batch_images": batch_images, "instructions": instructions, "state": state, **kwargs}
        return {"normalized_actions": normalized_for(payload, self.chunk)}


def route(model: StandInModel, message: dict, crash_on: str | None) -> dict:
    request_id, kind = message.get("request_id", "default"), message.get("type", "infer")
    payload = message.get("payload", message)
    if kind == "ping":
        return {"status": "ok", "ok": True, "type": "ping", "request_id": request_id}
    if kind != "infer":
        return {"status": "error", "ok": False, "type": "unknown", "request_id": request_id,
                "error": {"message": f"Unsupported message type '{kind}'"}}  # fmt: skip
    if crash_on and crash_on in payload["instructions"][0]:
        raise RuntimeError("an error the server does not catch")
    try:
        data = model.predict_action(**payload)
    except Exception as error:
        return {"status": "error", "ok": False, "type": "inference_result", "request_id": request_id,
                "error": {"message": str(error)}}  # fmt: skip
    return {"status": "ok", "ok": True, "type": "inference_result", "request_id": request_id, "data": data}


async def serve(port: int, model: StandInModel, crash_on: str | None) -> None:
    async def handler(websocket) -> None:
        packer = msgpack_numpy.Packer()
        await websocket.send(packer.pack({"env": "simpler_env"}))
        while True:
            try:
                message = msgpack_numpy.unpackb(await websocket.recv())
                await websocket.send(packer.pack(route(model, message, crash_on)))
            except websockets.ConnectionClosed:
                return
            except Exception:
                await websocket.send("Internal server error")
                await websocket.close(code=websockets.frames.CloseCode.INTERNAL_ERROR, reason="Internal server error")
                return

    async with websockets.asyncio.server.serve(handler, "127.0.0.1", port, compression=None, max_size=None) as server:
        await server.serve_forever()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--chunk", type=int, default=8)
    parser.add_argument("--fail-on")
    parser.add_argument("--crash-on")
    parser.add_argument("--die-on")
    args = parser.parse_args()
    model = StandInModel(args.chunk, args.fail_on, args.crash_on, args.die_on)
    asyncio.run(serve(args.port, model, args.crash_on))


if __name__ == "__main__":
    main()
