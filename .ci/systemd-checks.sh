#!/bin/sh
# Static checks of the systemd unit, udev rules and sysusers file (no running systemd needed):
#   systemd-analyze verify    (on a copy whose ExecStart points at /bin/true: verify insists the
#                              binary exists, and /opt/usb2rc is not installed in CI; the copy
#                              differs from the shipped unit in that one path, checked below)
#   systemd-analyze security  (offline; fails above MAX_EXPOSURE)
#   systemd-sysusers --root   (creates the user in a scratch root)
#   udevadm verify            (systemd >= 254; skipped with a note on older udev)
#   grep                      (RestartPreventExitStatus=2: a config error must not restart in a
#                              loop; Documentation= names the notes install-system writes)
set -eu

MAX_EXPOSURE=${MAX_EXPOSURE:-1.0}
here=$(cd "$(dirname "$0")/.." && pwd)
system="$here/usb2rc/data/system"  # package data: the wheel ships these (usb2rc install-system)
unit="$system/usb2rc.service"
rules="$system/70-usb2rc.rules"
sysusers="$system/usb2rc.sysusers"

if ! command -v systemd-analyze >/dev/null 2>&1; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq systemd >/dev/null
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

echo "== unit directives"
grep -qx 'RestartPreventExitStatus=2' "$unit" || { echo "no RestartPreventExitStatus=2" >&2; exit 1; }
grep -qx 'Documentation=file:/usr/share/doc/usb2rc/SERVICE.md' "$unit" || {
    echo "no Documentation= naming the installed SERVICE.md" >&2; exit 1; }
echo "present"

echo "== systemd-analyze verify"
sed 's|^ExecStart=/opt/usb2rc/venv/bin/usb2rc |ExecStart=/bin/true |' "$unit" >"$tmp/usb2rc.service"
changed=$(diff "$unit" "$tmp/usb2rc.service" | grep -c '^>' || true)
[ "$changed" -eq 1 ] || { echo "expected exactly the ExecStart line to change" >&2; exit 1; }
out=$(systemd-analyze verify "$tmp/usb2rc.service" 2>&1) || { echo "$out" >&2; exit 1; }
[ -z "$out" ] || { echo "$out" >&2; echo "verify printed warnings" >&2; exit 1; }
echo "clean"

echo "== systemd-analyze security"
report=$(systemd-analyze security --offline=true --no-pager "$unit" 2>&1) || true
exposure=$(printf '%s\n' "$report" | sed -n 's/.*Overall exposure level for [^:]*: \([0-9.]*\).*/\1/p')
[ -n "$exposure" ] || { echo "$report" >&2; echo "no exposure level found" >&2; exit 1; }
echo "exposure $exposure (max $MAX_EXPOSURE)"
awk -v e="$exposure" -v m="$MAX_EXPOSURE" 'BEGIN { exit !(e <= m) }' || {
    printf '%s\n' "$report" | grep '✗' >&2
    exit 1
}

echo "== systemd-sysusers"
mkdir -p "$tmp/root/etc"
systemd-sysusers --root="$tmp/root" - <"$sysusers" >/dev/null 2>&1
grep -q '^usb2rc:' "$tmp/root/etc/passwd"
echo "creates usb2rc"

echo "== udevadm verify"
if command -v udevadm >/dev/null 2>&1 && udevadm verify --help >/dev/null 2>&1; then
    udevadm verify "$rules"
    echo "clean"
else
    echo "skipped: udevadm verify needs systemd >= 254 (tests/test_systemd_unit.py lints the rules)"
fi
