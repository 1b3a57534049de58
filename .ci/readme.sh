#!/usr/bin/env bash
# The README's copy-paste examples, run as written; and every link in the repository's
# markdown checked. .ci/run calls this after the release binary exists; it runs on its own
# too (a developer's check):
#
#   .ci/readme.sh [README]   (a path from the repository root, default README.md; needs
#                            bash 5, git, python3, curl, setsid and timeout)
#
# 1. Links. In every markdown file git tracks (README.md, docs/*.md, ...), outside fenced
#    blocks: each link target ([text](target), ![alt](target), [ref]: target, <a href>,
#    <img src>) must be an http(s) URL or a path, relative to the file, to a file or
#    directory in the repository that git does not ignore; `#anchor`s into markdown files
#    must name a heading there. Code spans that name a repository path (`src/...`,
#    `tests/...`, `docs/...`: a `/` and a tracked top-level directory first) must exist too
#    (ignored paths such as generated output are let be). URLs are not fetched.
# 2. Blocks. Every ```sh block of the README, in order, from the repository root (where a
#    user who cloned the repository stands), with target/release first on PATH so that
#    `afterimage` is the binary CI built (the README's setup says to put it there, or to
#    `cargo install --path .`) and with no AFTERIMAGE_* variables set (built-in defaults,
#    as for a user). Each block runs in its own `bash` with `set -euo pipefail`, stdin
#    from /dev/null and a time limit (README_BLOCK_TIMEOUT, 300 s): a block must not rely
#    on variables or `cd` of an earlier one. A failing command stops the script, naming
#    its README line, and the block's number, README line and first line. Each block's
#    time is printed, and a table of them at the end.
#    Before the first block, the directories the blocks name as outputs (`--output DIR`,
#    `-o DIR`; only under /tmp or ignored by git) are removed, as on a fresh machine: the
#    frames of an earlier, longer run left there would be read back as part of a sequence.
#    Afterwards no file that git would list as untracked may have appeared: examples write
#    under ignored directories (out/, scenes/, report/) or /tmp.
#
# Marks: an HTML comment (invisible on GitHub) on the line just before a block's opening
# fence. Only these two exist; keep them few, every other block must run as written.
#   <!-- ci: skip (REASON) -->
#       The block is not run; REASON is printed. For what CI does elsewhere: the setup
#       block (cargo build --release, cargo test) that .ci/run has done by the time this
#       runs. A plain `cargo build --release` after .ci/run's release test build would
#       rebuild every dependency with the non-test feature set, for minutes.
#   <!-- ci: background (ready: COMMAND) -->
#       The block starts a long-running process (`afterimage serve`): it runs in the
#       background, in its own process group, for every later block. Before the next block
#       COMMAND is polled until it succeeds (60 s; it must fail before the block starts, so
#       that no stale server on the same port answers). At the end the group gets SIGTERM
#       and the block must exit 0 within 30 s (the server drains and stops cleanly).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
readme=${1:-README.md}
block_timeout=${README_BLOCK_TIMEOUT:-300}
export CARGO_TERM_COLOR=never

command -v python3 >/dev/null || { echo "readme.sh: python3 is needed (the README's examples use it)" >&2; exit 1; }
command -v curl >/dev/null || (apt-get update -qq && apt-get install -y -qq curl)
command -v setsid >/dev/null || { echo "readme.sh: setsid (util-linux) is needed" >&2; exit 1; }

work=$(mktemp -d)
bg_pids=() bg_blocks=()
stop_background() { # $1: "check" to require a clean exit; otherwise just stop them
  local i pid n rc failed=0 waited
  for i in "${!bg_pids[@]}"; do
    pid=${bg_pids[$i]} n=${bg_blocks[$i]}
    kill -TERM -- "-$pid" 2>/dev/null || true
    waited=0
    while kill -0 "$pid" 2>/dev/null && [ $waited -lt 300 ]; do sleep 0.1; waited=$((waited + 1)); done
    if kill -0 "$pid" 2>/dev/null; then
      kill -KILL -- "-$pid" 2>/dev/null || true
      echo "readme.sh: background block $n did not stop within 30 s of SIGTERM; killed" >&2
      failed=1
    fi
    rc=0
    wait "$pid" 2>/dev/null || rc=$?
    if [ "${1:-}" = check ]; then
      echo "-- background block $n stopped (exit $rc); its output:"
      if [ -s "$work/block_$n.log" ]; then sed 's/^/   | /' "$work/block_$n.log"; else echo "   (none)"; fi
      if [ $rc -ne 0 ]; then
        echo "readme.sh: background block $n exited $rc after SIGTERM, not 0" >&2
        failed=1
      fi
    fi
  done
  bg_pids=() bg_blocks=()
  return $failed
}
trap 'stop_background || true; rm -rf "$work"' EXIT

# The README's commands see a user's environment: built-in defaults, our binary on PATH.
# (.ci/run exports AFTERIMAGE_GRPC_ADDR and AFTERIMAGE_HTTP_ADDR for its own servers.)
while read -r var; do unset "$var"; done < <(compgen -e | grep '^AFTERIMAGE_' || true)
[ -x target/release/afterimage ] || cargo build --locked --release
if newer=$(find src crates Cargo.toml Cargo.lock -newer target/release/afterimage -print -quit) && [ -n "$newer" ]; then
  echo "readme.sh: warning: $newer is newer than target/release/afterimage; rebuild to test the current source" >&2
fi
export PATH="$root/target/release:$PATH"

now_us() { echo "${EPOCHREALTIME//[.,]/}"; }
secs() { printf '%d.%02d' $(($1 / 1000000)) $(($1 % 1000000 / 10000)); }
t_start=$(now_us)

python3 - "$readme" "$work" <<'PY'
import os, re, shutil, subprocess, sys, urllib.parse

readme, work = sys.argv[1], sys.argv[2]
fence_re = re.compile(r'^( *)(`{3,}|~{3,})\s*([^\s`]*)')


def parse_fences(lines):
    """Yields (kind, start, end, indent, info): 'code' spans [start, end] of fenced blocks."""
    i = 0
    while i < len(lines):
        m = fence_re.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, info = len(m.group(1)), m.group(2), m.group(3).lower()
        j = i + 1
        while j < len(lines):
            s = lines[j].strip()
            if s.startswith(fence[0] * len(fence)) and s.strip(fence[0]) == '':
                break
            j += 1
        yield i, j, indent, info
        i = j + 1


# ---- 1. links --------------------------------------------------------------------------
def git(*args):
    return subprocess.run(['git', *args], capture_output=True, text=True)


ls = git('ls-files', '-z')
in_git = ls.returncode == 0
tracked = [p for p in ls.stdout.split('\0') if p] if in_git else []
top_dirs = {p.split('/')[0] for p in tracked if '/' in p}
md_files = sorted(p for p in tracked if p.endswith('.md')) if in_git else \
    sorted(['README.md'] + ['docs/' + f for f in os.listdir('docs') if f.endswith('.md')])


def ignored(path):
    return in_git and git('check-ignore', '-q', path).returncode == 0


def slugs(path):
    """GitHub's heading anchors of a markdown file."""
    lines = open(path, encoding='utf-8').read().split('\n')
    code = set()
    for a, b, _, _ in parse_fences(lines):
        code.update(range(a, b + 1))
    seen, out = {}, set()
    for n, line in enumerate(lines):
        m = re.match(r' {0,3}#{1,6}\s+(.*?)\s*#*\s*$', line)
        if n in code or not m:
            continue
        text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', m.group(1))
        text = re.sub(r'<[^>]+>', '', text)
        slug = re.sub(r'[^\w\- ]', '', text.lower()).replace(' ', '-')
        k = seen.get(slug, 0)
        seen[slug] = k + 1
        out.add(slug if k == 0 else f'{slug}-{k}')
    return out


link_re = re.compile(r'!?\[((?:[^\[\]]|\[[^\[\]]*\])*)\]\(\s*(<[^>]*>|(?:[^()\s]|\([^()\s]*\))*)'
                     r'(?:\s+(?:"[^"]*"|\'[^\']*\'|\([^)]*\)))?\s*\)')
refdef_re = re.compile(r'^ {0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)', re.M)
html_re = re.compile(r'<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*["\']([^"\']*)["\']', re.I)
span_re = re.compile(r'(`+)(.+?)\1', re.S)
path_span_re = re.compile(r'^[A-Za-z0-9_.\-/]+$')

problems, checked = [], 0
for md in md_files:
    if not os.path.exists(md):
        continue
    lines = open(md, encoding='utf-8').read().split('\n')
    for a, b, _, _ in parse_fences(lines):
        for k in range(a, min(b, len(lines) - 1) + 1):
            lines[k] = ''
    text = '\n'.join(lines)
    line_of = lambda pos: text.count('\n', 0, pos) + 1
    spans = []

    def blank(m):  # code spans: kept for the path check, blanked for the link search
        spans.append((m.start(), m.group(2).strip()))
        return re.sub(r'[^\n]', ' ', m.group(0))
    prose = span_re.sub(blank, text)
    targets = [(m.start(), m.group(2)) for m in link_re.finditer(prose)]
    targets += [(m.start(), m.group(1)) for m in refdef_re.finditer(prose)]
    targets += [(m.start(), m.group(1)) for m in html_re.finditer(prose)]
    here = os.path.dirname(md)
    for pos, target in sorted(targets):
        checked += 1
        target = target.strip('<>')
        where = f'{md}:{line_of(pos)}: link ({target})'
        if re.match(r'https?://', target):
            continue
        if re.match(r'[A-Za-z][A-Za-z0-9+.\-]*:', target) or not target:
            problems.append(f'{where} is neither an http(s) URL nor a file in the repository')
            continue
        path, _, anchor = target.partition('#')
        path = urllib.parse.unquote(path)
        full = os.path.normpath(md if not path else
                                (path.lstrip('/') if path.startswith('/') else os.path.join(here, path)))
        if full == '..' or full.startswith('../') or os.path.isabs(full):
            problems.append(f'{where} points outside the repository')
        elif not os.path.exists(full):
            problems.append(f'{where}: {full} does not exist')
        elif ignored(full):
            problems.append(f'{where}: {full} is ignored by git (generated, not in the repository)')
        elif anchor and full.endswith('.md') and anchor.lower() not in slugs(full):
            problems.append(f'{where}: {full} has no heading with the anchor #{anchor}')
    for pos, span in spans:
        if not path_span_re.match(span) or '/' not in span or span.split('/')[0] not in top_dirs:
            continue
        checked += 1
        if not os.path.exists(span) and not ignored(span):
            problems.append(f'{md}:{line_of(pos)}: `{span}` names a path that does not exist')
print(f'== links: {checked} link targets and path code spans in {len(md_files)} markdown files')
if problems:
    print('\n'.join('readme.sh: broken: ' + p for p in problems), file=sys.stderr)
    sys.exit(1)

# ---- 2. the README's sh blocks -----------------------------------------------------------
lines = open(readme, encoding='utf-8').read().split('\n')
mark_re = re.compile(r'^\s*<!--\s*ci:(.*?)-->\s*$')
skip_re = re.compile(r'^\s*skip\s*\((.+)\)\s*$')
bg_re = re.compile(r'^\s*background\s*\(\s*ready:\s*(.+)\)\s*$')
errors, marks_used, manifest, outputs, n = [], set(), [], [], 0
for a, b, indent, info in parse_fences(lines):
    mark = mark_re.match(lines[a - 1]) if a > 0 else None
    if mark:
        marks_used.add(a - 1)
    if info != 'sh':
        if mark:
            errors.append(f'{readme}:{a}: a ci mark before a block that is not ```sh')
        continue
    n += 1
    body = [l[min(indent, len(l) - len(l.lstrip(' '))):] for l in lines[a + 1:b]]
    first = next((l.strip() for l in body if l.strip()), '(empty)')
    mode, arg = 'run', ''
    if mark:
        if m := skip_re.match(mark.group(1)):
            mode, arg = 'skip', m.group(1).strip()
        elif m := bg_re.match(mark.group(1)):
            mode, arg = 'background', m.group(1).strip()
        else:
            errors.append(f'{readme}:{a}: unknown ci mark {mark.group(0).strip()!r}: '
                          'only "ci: skip (REASON)" and "ci: background (ready: COMMAND)"')
    # Line 1 of the file is the header, so a command's README line is fence + LINENO - 1.
    head = 'set -euo pipefail; '
    # `cargo run --release -- ARGS` is `afterimage ARGS` from target/release, which .ci/run
    # built from the same sources (cargo run would rebuild the dependencies with the
    # non-test feature set first, for minutes).
    head += ('cargo() { if [ "${1-} ${2-} ${3-}" = "run --release --" ]; then shift 3; afterimage "$@"; '
             'else command cargo "$@"; fi; }; ')
    if mode == 'background':
        head += 'trap : TERM INT; '  # let the server drain; exit with its status
    head += ('trap \'__rc=$?; echo "readme.sh: %s:$((%d + LINENO - 1)): exit $__rc: $BASH_COMMAND" >&2\' ERR\n'
             % (readme, a + 1))
    with open(os.path.join(work, f'block_{n}.sh'), 'w') as f:
        f.write(head + '\n'.join(body) + '\n')
    manifest.append('\x1f'.join([str(n), str(a + 1), mode, arg, first]))
    if mode != 'skip':
        outputs += re.findall(r'(?:^|\s)(?:--output|-o)[\s=]+([^\s;|&$`\'"]+)(?=[\s;|&]|$)', '\n'.join(body))
for k, line in enumerate(lines):
    if mark_re.match(line) and k not in marks_used:
        errors.append(f'{readme}:{k + 1}: a ci mark not on the line just before a block\'s fence')
if errors:
    print('\n'.join('readme.sh: ' + e for e in errors), file=sys.stderr)
    sys.exit(1)
with open(os.path.join(work, 'manifest'), 'w') as f:
    f.write(''.join(m + '\n' for m in manifest))

removed = []
for out in dict.fromkeys(outputs):
    full = os.path.normpath(out)
    if os.path.isabs(full):
        safe = full.startswith('/tmp/')
    else:
        safe = full not in ('.', '..') and not full.startswith('../') and ignored(full)
    if not safe:
        print(f'readme.sh: note: not removing the output {out} before the run: neither under /tmp '
              'nor ignored by git', file=sys.stderr)
    elif os.path.isdir(full) and not os.path.islink(full):
        shutil.rmtree(full)
        removed.append(out)
    elif os.path.lexists(full):
        os.remove(full)
        removed.append(out)
if removed:
    print('== removed the outputs of an earlier run: ' + ' '.join(removed))
PY

untracked() { git status --porcelain --untracked-files=all 2>/dev/null | sed -n 's/^?? //p' | sort; }
untracked >"$work/untracked.before"

total=$(wc -l <"$work/manifest")
echo "== README blocks: $total sh blocks in $readme, run from $root with $(command -v afterimage)"
summary=()
while IFS=$'\x1f' read -r n line mode arg first; do
  label="block $n/$total ($readme:$line)"
  case $mode in
    skip)
      echo "== $label skipped: $arg"
      echo "   $first"
      summary+=("$(printf '%3s %5s  %-10s %8s  %s' "$n" "$line" skipped - "$first")")
      continue ;;
    background)
      echo "== $label in the background, ready when: $arg"
      echo "   $first"
      if bash -c "$arg" </dev/null >/dev/null 2>&1; then
        echo "readme.sh: $label: '$arg' succeeds before the block started: something else already serves there; stop it first" >&2
        exit 1
      fi
      t0=$(now_us)
      setsid bash "$work/block_$n.sh" </dev/null >"$work/block_$n.log" 2>&1 &
      pid=$!
      bg_pids+=("$pid") bg_blocks+=("$n")
      tries=0
      until bash -c "$arg" </dev/null >/dev/null 2>&1; do
        if ! kill -0 "$pid" 2>/dev/null; then
          rc=0; wait "$pid" || rc=$?
          sed 's/^/   | /' "$work/block_$n.log"
          echo "readme.sh: FAILED: $label exited $rc before it was ready: $first" >&2
          exit 1
        fi
        tries=$((tries + 1))
        if [ $tries -ge 300 ]; then
          sed 's/^/   | /' "$work/block_$n.log"
          echo "readme.sh: FAILED: $label not ready after 60 s ('$arg' kept failing): $first" >&2
          exit 1
        fi
        sleep 0.2
      done
      dt=$(($(now_us) - t0))
      echo "-- $label ready in $(secs $dt) s"
      summary+=("$(printf '%3s %5s  %-10s %8s  %s' "$n" "$line" background "$(secs $dt)" "$first")") ;;
    run)
      echo "== $label"
      sed "1d; s/^/   \$ /" "$work/block_$n.sh"
      t0=$(now_us)
      rc=0
      timeout -k 10 "$block_timeout" bash "$work/block_$n.sh" </dev/null || rc=$?
      dt=$(($(now_us) - t0))
      if [ $rc -ne 0 ]; then
        [ $rc -eq 124 ] && echo "readme.sh: $label ran past $block_timeout s" >&2
        echo "readme.sh: FAILED: $label (exit $rc, after $(secs $dt) s): $first" >&2
        exit 1
      fi
      echo "-- $label ok in $(secs $dt) s"
      summary+=("$(printf '%3s %5s  %-10s %8s  %s' "$n" "$line" ok "$(secs $dt)" "$first")") ;;
  esac
done <"$work/manifest"

stop_background check || exit 1

untracked >"$work/untracked.after"
if new=$(comm -13 "$work/untracked.before" "$work/untracked.after") && [ -n "$new" ]; then
  echo "readme.sh: the README's blocks left files that git does not ignore (write under out/, scenes/ or /tmp):" >&2
  echo "$new" | sed 's/^/  /' >&2
  exit 1
fi

echo "== README blocks passed in $(secs $(($(now_us) - t_start))) s"
printf '%3s %5s  %-10s %8s  %s\n' block line status seconds "first line"
printf '%s\n' "${summary[@]}"
