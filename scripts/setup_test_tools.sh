#!/usr/bin/env bash
# System tools that only some tests need, for the test command (scripts/test.sh), never the demo:
# - Debian's chromium + chromium-driver for the field view's browser test
#   (test/test_field_view_browser.py; EKF_NO_BROWSER=1 skips installing them);
# - iproute2 (ip netns, veth) for test/test_multi_host.py.
# Installed once with apt-get when this runs as root on a machine with apt; elsewhere those
# tests skip and say why.
set -uo pipefail
can_apt() { [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; }
want=()
if [ -z "${EKF_NO_BROWSER:-}" ] && { ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; }; then
  want+=(chromium chromium-driver)
fi
command -v ip >/dev/null 2>&1 || want+=(iproute2)
[ "${#want[@]}" -eq 0 ] && exit 0
if ! can_apt; then
  echo "setup_test_tools: not installed: ${want[*]} (apt-get install ${want[*]}); the tests that need them skip" >&2
  exit 0
fi
echo "setup_test_tools: installing ${want[*]} with apt-get (browser and multi-host tests)"
log="$(mktemp)"
if ! (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        "${want[@]}") >"$log" 2>&1; then
  tail -5 "$log" >&2
  echo "setup_test_tools: ${want[*]} not installed; the tests that need them skip" >&2
fi
rm -f "$log"
exit 0
