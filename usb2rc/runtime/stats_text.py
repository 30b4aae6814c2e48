"""The daemon's statistics as text: one line per output and per device, from the record
`Daemon.stats_record()` builds (the same record `run --stats-format json` prints whole).

Each counter's label lives here once; a key missing from a record (an output without RX, a
SUMD output without service frames) is left out of its line.
"""

from __future__ import annotations

from typing import Any

# record key -> how the text line shows it, in line order
OUTPUT_FIELDS: tuple[tuple[str, str], ...] = (
    ("writes", "writes {}"),
    ("ticks", "ticks {}"),
    ("late_ticks", "late {}"),
    ("missed_ticks", "missed {}"),
    ("period_p99_error_ms", "p99 |period error| {:.3f} ms"),
    ("tick_p99_ms", "p99 tick {:.3f} ms"),
    ("bytes_written", "bytes {}"),
    ("queue_full_skips", "queue-full skips {}"),
    ("write_timeouts", "write timeouts {}"),
    ("short_writes", "short writes {}"),
    ("stalls", "stalls {}"),
    ("stale_flushes", "stale flushes {}"),
    ("line_losses", "line losses {}"),
    ("tick_errors", "tick errors {}"),
    ("input_age_ms", "input age p50 {p50:.2f} / p99 {p99:.2f} / max {max:.2f} ms"),
    ("data_frames", "data frames {}"),
    ("service_frames", "service frames {}"),
    ("round_robin_deferrals", "round-robin deferrals {}"),
    ("handover_frames", "handover frames {}"),
    ("handovers_cut", "(cut by failsafe {})"),
    ("low_battery_frames", "low battery frames {}"),
    ("rx_bytes", "rx bytes {}"),
    ("rx_skipped", "rx skipped {}"),
    ("rx_crc_failures", "rx crc failures {}"),
    ("rx_requests", "requests {}"),
    ("rx_downlink_frames", "downlink frames {}"),
    ("rx_echo_frames", "its own frames come back (echo) {}"),
    ("rx_requests_dropped", "(dropped {})"),
    ("rx_dropped_bytes", "rx bytes dropped (faster than the line) {}"),
    ("module", "{}"),
    ("frames_withheld", "frames withheld (failsafe) {}"),
    ("module_rx_frames", "rx frames {}"),
    ("module_rx_crc_failures", "rx crc failures {}"),
    ("module_rx_skipped", "rx skipped {}"),
    ("module_rx_reads_dropped", "rx reads dropped (queue full) {}"),
    ("module_rx_link_statistics", "link statistics {}"),
    ("module_rx_battery", "battery {}"),
    ("module_rx_flight_mode", "flight mode {}"),
    ("module_rx_malformed", "malformed {}"),
    ("timing_corrections", "timing corrections {}"),
    ("timing_corrections_ignored", "(ignored {})"),
    ("mavlink_message", "{}"),
    ("control_messages", "control messages {}"),
    ("releases", "releases {}"),
    ("silent_failsafe_ticks", "silent failsafe ticks {}"),
    ("heartbeats_sent", "heartbeats {}"),
    ("far_end_messages", "far end: messages {}"),
    ("far_end_heartbeats", "heartbeats {}"),
    ("far_end_heartbeat_from", "(last from {})"),
    ("far_end_skipped", "bytes skipped {}"),
    ("vehicle", "vehicle {}"),
    ("vehicle_heartbeats", "its heartbeats {}"),
    ("vehicle_sys_status", "sys status {}"),
    ("vehicle_battery_status", "battery status {}"),
    ("other_vehicle_heartbeats", "other vehicles' heartbeats {}"),
    ("far_end_bad_signatures", "bad signatures {}"),
    ("actions_fired", "actions: fired {}"),
    ("actions_sent", "commands sent {}"),
    ("actions_acked", "acked {}"),
    ("actions_unanswered", "unanswered {}"),
    ("actions_refused", "refused {}"),
    ("actions_last", "last: {}"),
    ("udp_peer", "peer {}"),
    ("datagrams_from_peer", "datagrams from it {}"),
    ("datagrams_from_others", "from others ignored {}"),
    ("datagrams_not_allowed", "not allowed {}"),
    ("dozes", "asleep (nothing to send) {} times"),
)


def output_line(record: dict[str, Any]) -> str:
    fields = [
        _field(text, record[key]) for key, text in OUTPUT_FIELDS if record.get(key) is not None
    ]
    return f"{record['name']} {record['url']}: " + ", ".join(fields)


def _field(text: str, value: Any) -> str:
    """A counter (`text` with one place), or a record of named figures (`{p50}`...);
    None, a figure not measured yet, is left out by its caller."""
    return text.format(**value) if isinstance(value, dict) else text.format(value)


def device_line(record: dict[str, Any]) -> str:
    age = record["last_report_age_s"]
    line = (
        f"device {record['name']} ({record['port_path']}): "
        f"{record['reports']} reports ({record['reports_per_s']:.1f}/s avg), "
        f"bad {record['bad_reports']}, last report "
        + ("never" if age is None else f"{age:.2f} s ago")
    )
    if "backend_busy_ms" in record:
        line += f", backend busy {record['backend_busy_ms']:.1f} ms"
    if "kernel_queue_full" in record:
        line += f", kernel queue full {record['kernel_queue_full']} times (reports dropped)"
    if "pulled_between_steps_ms" in record:
        line += f", its reader pulls it every {record['pulled_between_steps_ms']:.1f} ms"
    if "outputs_written" in record:
        line += f", outputs written {record['outputs_written']}"
        line += f", refused {record['outputs_refused']}"
        if record.get("output_error"):
            line += f" ({record['output_error']})"
    return line


# telemetry source -> (label, unit) in the telemetry line, in order
TELEMETRY_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("crsf.link_quality", "LQ", " %"),
    ("crsf.rssi", "RSSI", " dBm"),
    ("crsf.snr", "SNR", " dB"),
    ("crsf.battery_voltage", "battery", " V"),
    ("crsf.battery_remaining", "", " %"),
    ("crsf.flight_mode", "mode", ""),
    ("mavlink.armed", "armed", ""),
    ("mavlink.mode", "mode", ""),
    ("mavlink.battery_voltage", "battery", " V"),
    ("mavlink.battery_remaining", "", " %"),
    ("mavlink.failsafe", "failsafe", ""),
)


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.1f}"
    return str(value)


def telemetry_line(values: dict[str, Any], source: str) -> str | None:
    """`crsf` or `mavlink` as the rules see it, with its age; None: never heard."""
    age = values.get(f"{source}.age")
    if age is None:
        return None
    parts = [
        f"{label} {_shown(values[key])}{unit}".strip()
        for key, label, unit in TELEMETRY_FIELDS
        if key.startswith(source + ".") and values.get(key) is not None
    ]
    shown = ", ".join(parts) if parts else "nothing known (stale)"
    return f"telemetry {source}: {shown} ({age:.1f} s ago)"


def feedback_lines(record: dict[str, Any]) -> list[str]:
    """The telemetry heard, each rule's last action, what each driven device shows."""
    values = record["telemetry"]
    lines = [line for s in ("crsf", "mavlink") if (line := telemetry_line(values, s))]
    lines += [
        f"feedback rule {a['rule']} ({a['where']}): {a['did']} ({a['ago_s']:.1f} s ago)"
        for a in record["actions"]
    ]
    for device in record["devices"]:
        shows = [f"lit {', '.join(device['lit'])}" if device["lit"] else "nothing lit"]
        shows += [f"{name} {value:.2f}" for name, value in device["analog"].items()]
        shows += [f"line {n} {text!r}" for n, text in enumerate(device["texts"], 1) if text]
        lines.append(f"feedback {device['name']}: " + ", ".join(shows))
    return lines


def missing_line(record: dict[str, Any]) -> str:
    where = f"; {record['where']}" if record.get("where") else ""
    return (
        f"missing: node {record['node_id']} config entry {record['entry']!r} "
        f"({record['match']}{where}): no device plugged, the node sends failsafe"
    )


def daemon_line(record: dict[str, Any]) -> str:
    """The daemon itself: how long it has run, the CPU it has taken since, how it is
    scheduled."""
    line = f"usb2rc: up {record['uptime_s']:.1f} s"
    if record.get("cpu_pct") is not None:
        line += f", CPU {record['cpu_pct']:.1f} % of a core since start"
        if record.get("drivers_cpu_pct") is not None:
            line += f" (drivers' thread {record['drivers_cpu_pct']:.1f} %)"
    if record.get("scheduling"):
        line += f", scheduling: {record['scheduling']}"
    return line


def stats_lines(record: dict[str, Any]) -> list[str]:
    return [
        daemon_line(record),
        *map(output_line, record["outputs"]),
        *map(device_line, record["devices"]),
        *map(missing_line, record.get("missing_devices", [])),
        *(feedback_lines(record["feedback"]) if "feedback" in record else []),
    ]
