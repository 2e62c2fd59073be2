"""Bounded load: concurrent GetStar calls (gRPC and REST) for a fixed count; every
answer must equal the star cut from the local mesh, and the server must stay healthy.
Throughput and latency are measured by bench/load.py, not here."""

from __future__ import annotations

import concurrent.futures
import random

import numpy as np
import spokemesh

from conftest import cli, http_json, local_mesh, star_of, uniform


def test_concurrent_stars_are_all_correct(server, tmp_path):
    points = uniform(5000, 3, seed=31)
    reference = local_mesh(points, tmp_path)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    rng = random.Random(20261122)
    seeds = [rng.randrange(5000) for _ in range(400)]

    def ask(i_seed):
        i, seed = i_seed
        if i % 4 == 3:  # a quarter through REST
            status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/{seed}/star")
            assert status == 200, body
            return seed, np.array(body["simplices"], dtype=np.int64)
        return seed, client.star(ps.id, seed).simplices.astype(np.int64)

    with concurrent.futures.ThreadPoolExecutor(max_workers=16) as pool:
        answers = list(pool.map(ask, enumerate(seeds)))
    assert len(answers) == len(seeds)
    for seed, simplices in answers:
        expected = star_of(reference, seed)
        assert np.array_equal(simplices, expected), f"seed {seed} (random.Random(20261122))"
    assert cli("health", "--server", server.grpc).stdout.strip() == "SERVING"
    assert http_json("GET", f"{server.http}/readyz")[0] == 200
