"""What two threads can give on this machine: a loop of arithmetic and a loop that streams memory, one thread
against more (:func:`pcdof.bench.machine.thread_bounds`; ``pcdof bench --only speed`` prints the same table).

    python scripts/thread_bound.py [--threads 1,2] [--megabytes 400] [--repeats 3]

A streaming speed-up well below the arithmetic one says the memory, not the cores, bounds passes that read and
write whole frames.
"""

import argparse

from pcdof.bench.machine import thread_bounds


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", default=None, help="thread counts, comma-separated [1, 2, 4, ... all]")
    parser.add_argument("--megabytes", type=float, default=400.0, help="memory the stream loop moves [400]")
    parser.add_argument("--repeats", type=int, default=3, help="runs per timing [3]")
    args = parser.parse_args(argv)
    counts = None if args.threads is None else [int(v) for v in args.threads.split(",")]
    for row in thread_bounds(counts, megabytes=args.megabytes, repeats=args.repeats):
        print(f"{row['threads']} thread(s): arithmetic {row['arithmetic_ms']:.1f} ms "
              f"({row['arithmetic_speedup']:.2f}x), stream {row['stream_ms']:.1f} ms ({row['stream_speedup']:.2f}x)")


if __name__ == "__main__":
    main()
