#!/bin/sh
# Install leadthrough on the cell PC (Debian; run as root from a clone of the repository):
#
#   sudo deploy/install.sh [PREFIX]        # PREFIX defaults to /opt/leadthrough
#
# Idempotent: run it again after `git pull` to update the code and the unit. It never
# overwrites /etc/leadthrough/cell.toml or the bus credentials once they exist.
#
# - the service user `leadthrough` (system user, no login shell);
# - the code in PREFIX with its own virtual environment and pinned dependencies;
# - /etc/leadthrough/cell.toml (from deploy/config/cell.toml: adapt the I/O module's IP);
# - /etc/leadthrough/bus.credentials: one random password per bus identity
#   (gateway/bus_security.py), mode 600, owned by the service user and readable by nobody
#   else: the cell's zenoh bus is locked to these identities;
# - the systemd unit, enabled but not started (`systemctl start leadthrough-gateway`).
#
# Operator commands on the cell PC run as the service user, so they can read the operator's
# credentials: `sudo -u leadthrough PREFIX/.venv/bin/leadthrough status --config
# /etc/leadthrough/cell.toml`.
set -eu

SRC=$(cd "$(dirname "$0")/.." && pwd)
PREFIX=${1:-/opt/leadthrough}
ETC=/etc/leadthrough
SERVICE_USER=leadthrough
IDENTITIES="gateway control can-driver modbus-driver operator observer"

if [ "$(id -u)" -ne 0 ]; then
    echo "install.sh: run as root (sudo $0)" >&2
    exit 1
fi

id -u "$SERVICE_USER" >/dev/null 2>&1 ||
    useradd --system --home-dir /var/lib/leadthrough --shell /usr/sbin/nologin "$SERVICE_USER"

mkdir -p "$PREFIX"
if [ "$SRC" != "$PREFIX" ]; then
    # the tracked files only: no virtual environment, caches or recordings of the clone
    (cd "$SRC" && git ls-files -z | xargs -0 tar cf -) | tar xf - -C "$PREFIX"
fi
make -C "$PREFIX" .venv/.installed

install -d -m 0750 -o root -g "$SERVICE_USER" "$ETC"
[ -e "$ETC/cell.toml" ] ||
    install -m 0640 -o root -g "$SERVICE_USER" "$SRC/deploy/config/cell.toml" "$ETC/cell.toml"

if [ ! -e "$ETC/bus.credentials" ]; then
    tmp=$(mktemp "$ETC/.bus.credentials.XXXXXX")  # mode 600 from the start
    for identity in $IDENTITIES; do
        printf '%s:%s\n' "$identity" "$(od -An -N24 -tx1 /dev/urandom | tr -d ' \n')"
    done >"$tmp"
    chown "$SERVICE_USER:$SERVICE_USER" "$tmp"
    chmod 600 "$tmp"
    mv "$tmp" "$ETC/bus.credentials"
fi

install -m 0644 "$SRC/deploy/systemd/leadthrough-gateway.service" /etc/systemd/system/
if [ "$PREFIX" != /opt/leadthrough ]; then
    sed -i "s|/opt/leadthrough|$PREFIX|g" /etc/systemd/system/leadthrough-gateway.service
fi
systemctl daemon-reload
systemctl enable leadthrough-gateway
echo "installed in $PREFIX; start with: systemctl start leadthrough-gateway"
