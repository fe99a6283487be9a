#!/usr/bin/env bash
# The session report shown in doc/recording.md, from a real run: kraft_master_record records
# a `kraft_master_demo --duration 20` run (the simulated device, the driver and the simulated
# slave pressing on its wall), then kraft_master_report draws the bag into
# doc/figures/session_report.png. Run it from anywhere after `make venv`; it prints the
# demo's last readout and the report's summary, the figures doc/recording.md quotes.
# ROS_DOMAIN_ID defaults to 97 here so that the run meets no other test's nodes.
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=.venv/bin
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-97} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
work=$(mktemp -d)
recorder=
cleanup() {
    if [ -n "$recorder" ] && kill -0 "$recorder" 2>/dev/null; then
        kill -INT "$recorder"
        wait "$recorder" || true
    fi
    rm -rf "$work"
}
trap cleanup EXIT
"$BIN/kraft_master_record" -o "$work/demo_bag" > "$work/record.log" 2>&1 &
recorder=$!
sleep 3
echo "load average before the run: $(cut -d' ' -f1-3 /proc/loadavg)"
"$BIN/kraft_master_demo" --duration 20 > "$work/demo.log" 2>&1
tail -n 9 "$work/demo.log"
kill -INT "$recorder"
wait "$recorder"
recorder=
tail -n 1 "$work/record.log"
"$BIN/kraft_master_report" "$work/demo_bag" --out "$work/report"
cp "$work/report/demo_bag_report.png" doc/figures/session_report.png
echo "wrote doc/figures/session_report.png"
