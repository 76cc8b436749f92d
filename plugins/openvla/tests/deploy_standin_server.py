"""A ``vla-scripts/deploy.py`` server as OpenVLA's or OpenVLA-OFT's behaves, hosting a numpy stand-in model.

Upstream's servers need the models' code and weights, which nothing installable carries, so this one restates
what their handlers do, with the same stack (FastAPI, uvicorn, ``json_numpy.patch()``): ``POST /act`` only; the
double-encoded ``{"encoded": ...}`` form; the JSON string ``"error"`` with HTTP 200 for any failure.

- ``--kind openvla``: the body's ``image`` (uint8) and ``instruction``, ``unnorm_key`` optional (the only key
  where missing); the model lower-cases the text into OpenVLA's prompt; the reply is one float64 action of 7,
  un-normalized with the key's q01/q99 where its mask keeps (the gripper stays the model's value).
- ``--kind oft``: ``full_image`` and every ``wrist*`` image, each resized where it is not 224 x 224 and then
  centre-cropped (the server's steps), the raw ``state`` normalized with the proprio q01/q99 (+1e-8, clipped);
  the ``unnorm_key`` fixed at start; the reply is a list of 8 float64 actions of 7 (q99 - q01 + 1e-8).

The stand-in model (``deploy_standin_model.py``) answers a fixed function of what reached it, so a test can tell
whether each processing step ran exactly once.

    python deploy_standin_server.py PORT --kind openvla|oft [--fail-on TEXT] [--die-on TEXT]
"""

from __future__ import annotations

import argparse
import os
import traceback

import json_numpy

json_numpy.patch()

import json  # noqa: E402  (after the patch, as deploy.py does)

import numpy as np  # noqa: E402
import uvicorn  # noqa: E402
from deploy_standin_model import PROPRIO, STATS, normalized_for, prompt_of, unnormalized  # noqa: E402
from fastapi import FastAPI  # noqa: E402
from fastapi.responses import JSONResponse  # noqa: E402

from conflictbench.hosting.openvla_family import center_crop, resize_for_policy  # noqa: E402
from conflictbench_openvla.processing import normalize_proprio  # noqa: E402


class StandIn:
    def __init__(self, kind: str, fail_on: str | None, die_on: str | None, unnorm_key: str):
        self.kind, self.fail_on, self.die_on, self.unnorm_key = kind, fail_on, die_on, unnorm_key

    def model(self, images: list[np.ndarray], instruction: str, key: str | None, proprio) -> np.ndarray:
        if self.die_on and self.die_on in instruction:
            os._exit(9)
        if self.fail_on and self.fail_on in instruction:
            raise RuntimeError("the model failed on purpose")
        if key is None:
            assert len(STATS) == 1, "unnorm_key needed: the checkpoint has several statistics"
        assert key in STATS, f"no statistics {key!r}"
        return normalized_for(images, prompt_of(instruction), proprio)

    def act(self, payload: dict):
        try:
            if double_encode := "encoded" in payload:
                assert len(payload.keys()) == 1
                payload = json.loads(payload["encoded"])
            action = self.openvla(payload) if self.kind == "openvla" else self.oft(payload)
            return JSONResponse(json_numpy.dumps(action)) if double_encode else JSONResponse(action)
        except Exception:  # deploy.py: a bare except, the traceback logged, "error" answered
            traceback.print_exc()
            return "error"

    def openvla(self, payload: dict) -> np.ndarray:
        image = payload["image"]
        assert isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
        key = payload.get("unnorm_key", None)
        normalized = self.model([image], payload["instruction"], key, None)[0]
        return unnormalized(normalized, STATS[key]["action"], 0.0)

    def oft(self, payload: dict) -> list[np.ndarray]:
        images = [payload["full_image"]] + [payload[k] for k in payload if "wrist" in k]
        assert len(images) == 2, "num_images_in_input 2: one wrist image"
        prepared = []
        for image in images:
            assert isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.shape[2] == 3
            if image.shape != (224, 224, 3):
                image = resize_for_policy(image)
            prepared.append(center_crop(image))
        stats = STATS[self.unnorm_key]
        proprio = normalize_proprio(payload["state"], PROPRIO)  # OFT's step, as the plugin pins it
        normalized = self.model(prepared, payload["instruction"], self.unnorm_key, proprio)
        actions = unnormalized(normalized, stats["action"], 1e-8)
        return [actions[i] for i in range(len(actions))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--kind", choices=["openvla", "oft"], required=True)
    parser.add_argument("--fail-on")
    parser.add_argument("--die-on")
    parser.add_argument("--unnorm-key", default="libero_goal", help="OFT: fixed at start")
    args = parser.parse_args()
    standin = StandIn(args.kind, args.fail_on, args.die_on, args.unnorm_key)
    app = FastAPI()
    app.post("/act")(standin.act)
    uvicorn.run(app, host="127.0.0.1", port=args.port, log_level="warning")


if __name__ == "__main__":
    main()
