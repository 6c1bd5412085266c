"""One side of the re-dial repro: a session from a JSON config, 10 Hz (gcs) or 100 Hz (drone) best-effort
puts, a liveliness token, every arrival's time written to <config>.arr (run.py drives it)."""
import sys
import time

import zenoh

role, cfg_path, dur = sys.argv[1], sys.argv[2], float(sys.argv[3])
zenoh.init_log_from_env_or("error")
s = zenoh.open(zenoh.Config.from_json5(open(cfg_path).read()))
out = open(cfg_path.replace(".json", ".arr"), "w")
peer_key = "sp" if role == "drone" else "sensor"
sub = s.declare_subscriber(peer_key, lambda sample: out.write(f"{time.time():.3f} {peer_key}\n"))
tok = s.liveliness().declare_token(f"tok/{role}")
lsub = s.liveliness().declare_subscriber(
    "tok/**", lambda sample: out.write(f"{time.time():.3f} LIV {sample.kind} {sample.key_expr}\n"), history=True)
pub = s.declare_publisher("sensor" if role == "drone" else "sp", congestion_control=zenoh.CongestionControl.DROP,
                          reliability=zenoh.Reliability.BEST_EFFORT)
period, size = (0.01, 200) if role == "drone" else (0.1, 100)
end, n = time.time() + dur, 0
while time.time() < end:
    pub.put(b"x" * size)
    n += 1
    if n % 20 == 0:
        out.flush()
    time.sleep(period)
out.close()
s.close()
