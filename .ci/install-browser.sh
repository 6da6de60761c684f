#!/usr/bin/env bash
# Headless Chromium and its WebDriver (Debian packages) for the web viewer's browser test; every
# failure is tolerated (the test then skips and says why).
command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1 && exit 0
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  (DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null 2>&1 \
   || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver) >/dev/null 2>&1) \
   || echo "note: chromium not installed; the browser test of the web viewer will skip"
else
  echo "note: no root/apt; the browser test of the web viewer will skip"
fi
exit 0
