#!/usr/bin/env python3
"""Interop check of a `sparkout replay --bus log:FILE` log (run by
tests/replay_cli.rs when python-can and cantools are installed):

- python-can's candump log reader (can.CanutilsLogReader) reads every line;
- every PDO frame (RPDO1/TPDO1 of the DBC) decodes with cantools using the
  shipped configs/can/cia402_pdo.dbc, and the decoded position equals the
  little-endian int32 in the frame times the DBC factor;
- timestamps never go backwards; SYNC frames come at one fixed period.

Usage: check_candump.py LOG DBC
"""
import sys

import can
import cantools


def main(log_path, dbc_path):
    db = cantools.database.load_file(dbc_path)
    pdo = {m.frame_id: m for m in db.messages if m.name.startswith(("RPDO", "TPDO"))}
    lines = sum(1 for line in open(log_path) if line.strip())
    frames = 0
    decoded = 0
    last_t = -1.0
    syncs = []
    for msg in can.CanutilsLogReader(log_path):
        frames += 1
        if msg.timestamp < last_t:
            raise SystemExit(f"timestamp goes backwards at frame {frames}: {msg.timestamp} < {last_t}")
        last_t = msg.timestamp
        if msg.is_error_frame:
            continue
        if msg.arbitration_id == 0x080:
            syncs.append(msg.timestamp)
        m = pdo.get(msg.arbitration_id)
        if m is None:
            continue
        values = m.decode(bytes(msg.data))
        key = "TargetPosition" if m.name.startswith("RPDO") else "ActualPosition"
        raw = int.from_bytes(bytes(msg.data[2:6]), "little", signed=True)
        scale = m.get_signal_by_name(key).scale
        if abs(values[key] - raw * scale) > 1e-9:
            raise SystemExit(f"{m.name}: cantools says {values[key]}, the frame holds {raw} counts")
        decoded += 1
    if frames != lines:
        raise SystemExit(f"python-can read {frames} frames from {lines} lines")
    if decoded == 0:
        raise SystemExit("no PDO frame in the log")
    periods = sorted({round(b - a, 6) for a, b in zip(syncs, syncs[1:])})
    if len(periods) != 1:
        raise SystemExit(f"SYNC periods vary: {periods[:5]}")
    print(f"interop ok: {frames} frames read by python-can, {decoded} PDO frames decoded by cantools, "
          f"{len(syncs)} SYNC every {periods[0] * 1000:.3f} ms")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
