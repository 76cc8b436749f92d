"""A ``conflictbench-serve univla`` stand-in: our UniVLA protocol (``conflictbench_univla.protocol``), a numpy model.

UniVLA's model code is in no installable package; this server answers as ours does (json-numpy ``POST /act``,
``GET /metadata``, ``{"error": ...}`` with HTTP 500) with a model whose answer is a fixed function of what reached
it (``univla_standin_model.py``), so a test can tell that each step ran exactly once.

    python univla_standin_server.py PORT [--fail-on TEXT] [--die-on TEXT] [--no-metadata]
"""

import argparse
import os

import json_numpy
import numpy as np
import uvicorn
from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response
from univla_standin_model import STATISTICS, WINDOW, chunk_for, latent_tokens, prompt_of

NOISE_SEED = "conflictbench/noise_seed"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--fail-on")
    parser.add_argument("--die-on")
    parser.add_argument("--no-metadata", action="store_true")
    parser.add_argument("--no-noops", action="store_true", help="statistics keys named libero_*_no_noops")
    args = parser.parse_args()
    statistics = {f"{key}_no_noops": value for key, value in STATISTICS.items()} if args.no_noops else STATISTICS
    app = FastAPI()

    @app.post("/act")
    async def act(request: Request):
        payload = json_numpy.loads(await request.body())
        instruction = payload["instruction"]
        if args.die_on and args.die_on in instruction:
            os._exit(9)
        if args.fail_on and args.fail_on in instruction:
            return JSONResponse({"error": "RuntimeError: the model failed on purpose"}, status_code=500)
        image = payload["image"]
        assert isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.shape == (224, 224, 3)
        assert payload["unnorm_key"] in statistics
        prompt, seed = prompt_of(instruction, payload["history"]), int(payload[NOISE_SEED])
        tokens = latent_tokens(prompt, seed)
        if "briefly" in instruction:  # fewer latent tokens came out (upstream keeps those it got)
            tokens = tokens[:3]
        reply = {"actions": chunk_for(image, prompt, seed), "latent_tokens": tokens}
        return Response(json_numpy.dumps(reply), media_type="application/json")

    if not args.no_metadata:

        @app.get("/metadata")
        async def metadata():
            return {"policy_type": "univla", "checkpoint_fingerprint": "sha256:standin", "max_batch": 1,
                    "window": WINDOW, "action_statistics": statistics}  # fmt: skip

    uvicorn.run(app, host="127.0.0.1", port=args.port, log_level="warning")


if __name__ == "__main__":
    main()
