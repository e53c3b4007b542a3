# Sourced by scripts/setup.sh: apt-get that waits for a held apt/dpkg lock instead of failing.
#
# Another apt-get, dpkg or unattended-upgrades run holds /var/lib/dpkg/lock-frontend (or the dpkg / apt
# lists locks) for minutes on a fresh machine. `apt_get ARGS...` waits while a lock file is held
# (`fuser`, when installed) and retries while apt-get says "Could not get lock" / "Unable to acquire the
# dpkg frontend lock", saying so every KILN_APT_LOCK_POLL seconds (default 5), for at most
# KILN_APT_LOCK_WAIT seconds in all (default 600); then it fails with apt-get's own message.

KILN_APT_LOCKS="${KILN_APT_LOCKS:-/var/lib/dpkg/lock-frontend /var/lib/dpkg/lock /var/lib/apt/lists/lock /var/cache/apt/archives/lock}"

_apt_lock_log() { printf 'kiln setup: %s\n' "$*" >&2; }

# The pids holding any apt/dpkg lock (empty when none or when fuser is missing).
apt_lock_holders() {
  command -v fuser >/dev/null 2>&1 || return 0
  local f out=""
  for f in $KILN_APT_LOCKS; do
    [ -e "$f" ] || continue
    out="$out $(fuser "$f" 2>/dev/null || true)"
  done
  echo $out
}

apt_get() {
  local limit="${KILN_APT_LOCK_WAIT:-600}" poll="${KILN_APT_LOCK_POLL:-5}"
  local start=$SECONDS err rc holders
  err=$(mktemp)
  while :; do
    holders=$(apt_lock_holders)
    if [ -n "$holders" ]; then
      if [ $((SECONDS - start)) -ge "$limit" ]; then
        _apt_lock_log "the apt/dpkg lock is still held (pid $holders) after ${limit} s; giving up (KILN_APT_LOCK_WAIT)"
        rm -f "$err"
        return 100
      fi
      _apt_lock_log "another process holds the apt/dpkg lock (pid $holders): waiting ($((SECONDS - start)) s of at most ${limit} s)"
      sleep "$poll"
      continue
    fi
    rc=0
    DEBIAN_FRONTEND=noninteractive apt-get "$@" 2>"$err" || rc=$?
    if [ "$rc" -ne 0 ] && grep -qiE 'could not get lock|unable to acquire the dpkg frontend lock|unable to lock|is another process using it' "$err"; then
      if [ $((SECONDS - start)) -ge "$limit" ]; then
        cat "$err" >&2
        _apt_lock_log "the apt/dpkg lock is still held after ${limit} s; giving up (KILN_APT_LOCK_WAIT)"
        rm -f "$err"
        return "$rc"
      fi
      _apt_lock_log "apt-get could not get the apt/dpkg lock (another apt-get, dpkg or unattended-upgrades runs): retrying in ${poll} s ($((SECONDS - start)) s of at most ${limit} s)"
      sleep "$poll"
      continue
    fi
    cat "$err" >&2
    rm -f "$err"
    return "$rc"
  done
}
