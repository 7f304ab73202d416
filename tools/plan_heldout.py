#!/usr/bin/env python3
"""Plans a held-out scenario set once, in resumable chunks, for `wheelleg eval --planner-results`.

    python3 tools/plan_heldout.py [SCENARIOS.json] [--chunk 100] [--max-expansions 5000]
                                  [--jobs 1] [--wheelleg target/release/wheelleg]

Default set: eval/heldout-complex-s1000000.json (1,000 complex scenes, seed 1,000,000, the
held-out seed of docs/results.md). The planner takes seconds per cluttered scene, so a pass over
1,000 scenes is about an hour of one core (--jobs plans that many chunks at once, one core
each): each chunk's result is written atomically to SCENARIOS.plan.d/chunkK.json as it
finishes, a rerun plans only the missing chunks, and once all are there they are merged into
SCENARIOS.plan.json (the `wheelleg plan --json` shape).
"""
import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import tempfile


def write_atomic(path, text):
    folder = os.path.dirname(path) or "."
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(here)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenarios", nargs="?",
                   default=os.path.join(root, "eval", "heldout-complex-s1000000.json"))
    p.add_argument("--chunk", type=int, default=100)
    p.add_argument("--max-expansions", type=int, default=5000)
    p.add_argument("--jobs", type=int, default=1, help="chunks planned at once (one core each)")
    p.add_argument("--wheelleg", default=os.path.join(
        os.environ.get("CARGO_TARGET_DIR", os.path.join(root, "target")), "release", "wheelleg"))
    args = p.parse_args()
    if args.chunk < 1:
        sys.exit("--chunk must be at least 1")
    if args.jobs < 1:
        sys.exit("--jobs must be at least 1")
    try:
        with open(args.scenarios) as f:
            scenarios = json.load(f)["scenarios"]
    except (OSError, ValueError, KeyError) as e:
        sys.exit(f"{args.scenarios}: not a scenario file ({e})")
    base = args.scenarios[:-5] if args.scenarios.endswith(".json") else args.scenarios
    chunks_dir = base + ".plan.d"
    os.makedirs(chunks_dir, exist_ok=True)
    count = (len(scenarios) + args.chunk - 1) // args.chunk

    def chunk_path(k):
        return os.path.join(chunks_dir, f"chunk{k}.json")

    def names_of(k):
        return [s["name"] for s in scenarios[k * args.chunk:(k + 1) * args.chunk]]

    def plan_chunk(k):
        """Plans chunk k into its file; returns an error message or None."""
        part = scenarios[k * args.chunk:(k + 1) * args.chunk]
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
            json.dump({"scenarios": part}, f)
            chunk_file = f.name
        try:
            print(f"planning chunk {k + 1}/{count} ({len(part)} scenes)", flush=True)
            run = subprocess.run(
                [args.wheelleg, "plan", "--scenarios", chunk_file, "--json",
                 "--max-expansions", str(args.max_expansions)],
                capture_output=True, text=True)
        finally:
            os.unlink(chunk_file)
        if run.returncode != 0:
            return f"wheelleg plan failed on chunk {k}: {run.stderr.strip()}"
        write_atomic(chunk_path(k), json.dumps(
            {"max_expansions": args.max_expansions,
             "results": json.loads(run.stdout)["results"]}, indent=1))
        return None

    missing = [k for k in range(count) if not os.path.exists(chunk_path(k))]
    with concurrent.futures.ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for error in pool.map(plan_chunk, missing):
            if error:
                sys.exit(error)
    results = []
    for k in range(count):
        with open(chunk_path(k)) as f:
            stored = json.load(f)
        done = stored["results"]
        if stored.get("max_expansions") != args.max_expansions:
            sys.exit(f"{chunk_path(k)} was planned with --max-expansions "
                     f"{stored.get('max_expansions')}, not {args.max_expansions}")
        if [r["name"] for r in done] != names_of(k):
            sys.exit(f"{chunk_path(k)} plans other scenarios than chunk {k} of "
                     f"{args.scenarios}; delete it (or the folder) to plan again")
        results.extend(done)
    merged = base + ".plan.json"
    write_atomic(merged, json.dumps({"results": results}, indent=1))
    shortest = sum(1 for r in results if r.get("shortest"))
    print(f"wrote {merged}: {len(results)} scenes, {shortest} with a proven shortest path "
          f"within {args.max_expansions} expansions")


if __name__ == "__main__":
    main()
