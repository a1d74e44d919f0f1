#!/bin/sh
# Checks that README.md shows the code of tests/readme_example.cpp between
# its README-BEGIN / README-END markers, line for line.
set -eu
readme="$1"; example="$2"
want=$(awk '/README-BEGIN/{f=1; next} /README-END/{f=0} f' "$example")
got=$(awk '/<!-- example: tests\/readme_example.cpp -->/{f=1; next} f && /^```cpp/{c=1; next} c && /^```/{exit} c' "$readme")
if [ "$want" != "$got" ]; then
  echo "README.md's library example differs from tests/readme_example.cpp:" >&2
  diff <(echo "$want") <(echo "$got") >&2 2>/dev/null || { echo "--- example"; echo "$want"; echo "--- README"; echo "$got"; } >&2
  exit 1
fi
echo "README example in sync"
