"""Every command in README.md and docs/*.md is checked (`make docs-check`).

The shell lines of the fenced ```bash / ```sh / ```console blocks (in console blocks, the lines after a `$ `
prompt) are read as bash reads them: `\\` joins lines, `#` starts a comment, `|`, `&&`, `||` and `;`
separate commands, `NAME=value` before a command sets its environment. Each command is checked by kind:

- `walkdiff <tool> ...` against the real parser (`walkdiff.cli.main.build_parser`);
- `walkdiff fit|validate|test --config X ...`: X is in conf/ (or written by a `walkdiff data scan --out`
  of the same page), and LightningCLI accepts the overrides (`--print_config`), once per distinct line;
- `make TARGET VAR=value`: the target and the variable are the Makefile's, a path value exists;
- `mlflow <command> ...` against mlflow's own click parser (nothing is run);
- `python FILE`, `python -m MODULE`, `python -m pytest FILE`, `python -c CODE`: the file or module exists,
  the code compiles.

Commands of any other program fail, unless SKIPPED names it with the reason. Beside the commands: every
relative link (and its #anchor) points at an existing file and heading, every repository path written in
inline code exists, the checkpoint paths the pages sample from are the ones the configs write, the
README stays the front door (at most 250 lines), and every figure it quotes is the one its page or config
holds (README_FIGURES).

The quick start itself (train the evaluator and the generator from their configs, then sample) runs end to
end in tests/test_own_data.py::test_scan_then_fit_sample_and_transfer_on_disguised_xia, on configs that
`data scan` models on conf/evaluator_xia.yaml and conf/xia_cpu.yaml; `make ui`'s server on a real fit run is
tests/test_mlflow_ui.py. Here only the path that joins them is checked
(test_checkpoint_paths_are_where_the_configs_write_them).
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import shlex
import warnings
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest
import synthetic

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
README_MAX_LINES = 250
SHELL_BLOCKS = ("bash", "sh", "console")
SEPARATORS = {"|", "||", "&&", ";", "&"}
REDIRECTIONS = {"<", ">", ">>", "2>", "&>"}
LIGHTNING_VERBS = ("fit", "validate", "test")
PYTHONS = {"python", "python3", ".venv/bin/python"}
WALKDIFFS = {"walkdiff", ".venv/bin/walkdiff"}
# Programs whose lines are not checked, and why.
SKIPPED = {
    "export": "sets an environment variable for the commands after it",
    "source": "activates the virtual environment (`source .venv/bin/activate`)",
    "printf": "writes the input of the next command of its pipeline (which is checked)",
}


@dataclass(frozen=True)
class Command:
    page: str  # path relative to the repository
    line: int  # where the command starts
    words: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}: {shlex.join(self.words)}"


def relative(path: Path) -> str:
    return str(path.relative_to(ROOT))


def fenced_blocks(text: str):
    """(language, first line number of the body, body lines) of every fenced block."""
    language, start, body = None, 0, []
    for number, line in enumerate(text.splitlines(), 1):
        fence = re.match(r"^\s*```(\S*)", line)
        if fence and language is None:
            language, start, body = fence.group(1).lower(), number + 1, []
        elif fence:
            yield language, start, body
            language = None
        elif language is not None:
            body.append(line)


def strip_comment(line: str) -> str:
    """The line without its `#` comment (a `#` that starts a word, outside quotes)."""
    quote = None
    for i, char in enumerate(line):
        if quote:
            quote = None if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def logical_lines(language: str, start: int, body: list[str]):
    """(line number, text) of each command line of a block: comments gone, continuations joined."""
    pending, first = "", None
    for number, raw in enumerate(body, start):
        if language == "console" and first is None:
            if not raw.startswith("$ "):
                continue  # output, not a command
            raw = raw[2:]
        text = strip_comment(raw).rstrip()
        if first is None:
            first = number
        if text.endswith("\\"):
            pending += text[:-1] + " "
            continue
        yield first, pending + text
        pending, first = "", None
    if pending.strip():
        yield first, pending


def split_commands(text: str) -> list[list[str]]:
    """The simple commands of a line, without redirections and leading VAR=value assignments."""
    lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = ""
    commands, words, skip_next = [], [], False
    for token in lexer:
        if skip_next:
            skip_next = False
        elif token in SEPARATORS:
            commands.append(words)
            words = []
        elif token in REDIRECTIONS:
            skip_next = True
        else:
            words.append(token)
    commands.append(words)
    result = []
    for words in commands:
        while words and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", words[0]):
            words = words[1:]
        if words[:1] == ["walkdiff"]:  # global options, which `main` takes off before parsing
            from walkdiff.cli.main import _pop_threads

            _pop_threads(words)
        if words:
            result.append(words)
    return result


def collect_commands() -> list[Command]:
    commands = []
    for page in PAGES:
        for language, start, body in fenced_blocks(page.read_text()):
            if language not in SHELL_BLOCKS:
                continue
            for number, text in logical_lines(language, start, body):
                commands += [Command(relative(page), number, tuple(w)) for w in split_commands(text)]
    return commands


COMMANDS = collect_commands()


def of_kind(kind: set[str]) -> list[Command]:
    return [c for c in COMMANDS if c.words[0] in kind]


def ids(commands: list[Command]) -> list[str]:
    return [f"{c.page}:{c.line}" for c in commands]


# ---------------------------------------------------------------- what the collector reads


def test_the_collector_reads_lines_as_bash_does():
    block = [
        "walkdiff sample --ckpt a.ckpt \\",
        "    --style old  # a comment: --not-an-option",
        "# a whole-line comment",
        "OMP_NUM_THREADS=1 walkdiff bench gesture --out b.json",
        "printf '{\"x\": 0}\\n' | walkdiff walk --path - --out o && make ui",
        "walkdiff score d --pattern '^(?P<style>[a-z]+)_' --out e > log.txt",
    ]
    lines = list(logical_lines("bash", 10, block))
    assert lines[0] == (10, "walkdiff sample --ckpt a.ckpt      --style old")
    commands = [words for _, text in lines for words in split_commands(text)]
    assert commands == [
        ["walkdiff", "sample", "--ckpt", "a.ckpt", "--style", "old"],
        ["walkdiff", "bench", "gesture", "--out", "b.json"],
        ["printf", '{"x": 0}\\n'],
        ["walkdiff", "walk", "--path", "-", "--out", "o"],
        ["make", "ui"],
        ["walkdiff", "score", "d", "--pattern", "^(?P<style>[a-z]+)_", "--out", "e"],
    ]
    console = ["$ walkdiff --help", "usage: walkdiff [-h] COMMAND ...", "$ make test"]
    assert [text for _, text in logical_lines("console", 1, console)] == ["walkdiff --help", "make test"]


def test_the_pages_have_commands_and_every_one_is_of_a_known_kind():
    assert len(COMMANDS) > 50
    known = WALKDIFFS | PYTHONS | {"make", "mlflow"} | set(SKIPPED)
    unknown = [c.where for c in COMMANDS if c.words[0] not in known]
    assert not unknown, (
        "commands of programs this test cannot check (add a check, or SKIPPED with why):\n"
        + ("\n".join(unknown))
    )


# ---------------------------------------------------------------- walkdiff tools

TOOLS = [c for c in of_kind(WALKDIFFS) if len(c.words) < 2 or c.words[1] not in LIGHTNING_VERBS]


@pytest.mark.parametrize("command", TOOLS, ids=ids(TOOLS))
def test_walkdiff_commands_parse(command):
    from walkdiff.cli.main import build_parser

    try:
        build_parser().parse_args(list(command.words[1:]))
    except SystemExit as stop:  # --help
        assert stop.code == 0, f"{command.where}: exit {stop.code}"
    except Exception as error:  # UsageError (a WalkdiffError) and anything else the parser raises
        pytest.fail(f"{command.where}: {type(error).__name__}: {error}")


# ---------------------------------------------------------------- walkdiff fit / validate / test

LIGHTNING = [c for c in of_kind(WALKDIFFS) if len(c.words) > 1 and c.words[1] in LIGHTNING_VERBS]


def config_of(command: Command) -> str:
    words = list(command.words)
    assert "--config" in words, f"{command.where}: no --config"
    return words[words.index("--config") + 1]


def scan_lines(page: str) -> list[Command]:
    return [c for c in of_kind(WALKDIFFS) if c.page == page and c.words[1:3] == ("data", "scan")]


def scan_output(command: Command) -> tuple[str, str]:
    """The --out folder and the config name of a documented `data scan`."""
    from walkdiff.cli.main import build_parser
    from walkdiff.data.scan import config_name

    args = build_parser().parse_args(list(command.words[1:]))
    assert args.out, f"{command.where}: a scan whose configs are trained needs --out"
    return args.out.rstrip("/"), config_name(args.name or Path(args.folder).name)


def written_config(config: str, page: str, folder: Path) -> Path | None:
    """`config` as written by a `data scan --out` of `page`, made here from a small synthetic folder."""
    from walkdiff.cli.main import main

    for scan in scan_lines(page):
        out, name = scan_output(scan)
        if config not in (f"{out}/{name}.yaml", f"{out}/evaluator_{name}.yaml"):
            continue
        data = synthetic.xia_like_folder(folder, walk_clips=3, frames=120)
        target = folder / "conf"
        labels = ["--pattern", "^(?P<style>[a-z]+)_", "--default-content", "walk"]
        assert (
            main(["data", "scan", str(data), "--out", str(target), "--name", name, *labels, "--no-timing"])
            == 0
        )
        return target / Path(config).name
    return None


GROUPS: dict[str, list[Command]] = defaultdict(list)
for _command in LIGHTNING:
    GROUPS[config_of(_command)].append(_command)


@pytest.mark.parametrize("config", sorted(GROUPS))
def test_lightning_configs_exist_and_take_their_overrides(config, tmp_path, monkeypatch, capsys):
    from walkdiff.callbacks.fit import lightning_cli

    monkeypatch.setattr("sys.argv", ["walkdiff"])  # LightningCLI warns about pytest's own arguments
    commands = GROUPS[config]
    if Path(config).parts[0] == "conf":
        path = ROOT / config
        assert path.is_file(), f"{commands[0].where}: {config} is not in conf/"
    else:
        path = written_config(config, commands[0].page, tmp_path)
        assert path is not None and path.is_file(), (
            f"{commands[0].where}: {config} is neither in conf/ nor written by a `walkdiff data scan --out` "
            f"of {commands[0].page}"
        )
    seen = set()
    for command in commands:
        words = list(command.words[1:])
        words[words.index("--config") + 1] = str(path)
        if tuple(words) in seen:
            continue
        seen.add(tuple(words))
        try:
            lightning_cli([*words, "--print_config"])
        except SystemExit as stop:
            assert stop.code == 0, f"{command.where}: exit {stop.code}"
        except Exception as error:
            pytest.fail(f"{command.where}: {type(error).__name__}: {error}")
        else:
            pytest.fail(f"{command.where}: --print_config did not stop")
        capsys.readouterr()


# ---------------------------------------------------------------- make

MAKEFILE = (ROOT / "Makefile").read_text()
TARGETS = {
    name
    for match in re.finditer(r"^([A-Za-z0-9_.$() /-]+?)\s*:(?!=)", MAKEFILE, re.M)
    for name in match.group(1).split()
}
VARIABLES = set(re.findall(r"^([A-Za-z_][A-Za-z0-9_]*)\s*[:?+]?=", MAKEFILE, re.M))
MAKES = of_kind({"make"})


@pytest.mark.parametrize("command", MAKES, ids=ids(MAKES))
def test_make_targets_exist(command):
    for word in command.words[1:]:
        if "=" in word:
            name, value = word.split("=", 1)
            assert name in VARIABLES, f"{command.where}: the Makefile has no variable {name}"
            if "/" in value:
                assert (ROOT / value).exists(), f"{command.where}: {value} does not exist"
        elif not word.startswith("-"):
            assert word in TARGETS, f"{command.where}: the Makefile has no target {word}"


def test_the_makefile_reader_sees_the_targets():
    assert {"install", "test", "train", "evaluator", "ui", "lint", "docs-check"} <= TARGETS
    assert {"CONFIG", "UI_PORT"} <= VARIABLES


# ---------------------------------------------------------------- mlflow

MLFLOWS = of_kind({"mlflow"})


@pytest.mark.parametrize("command", MLFLOWS, ids=ids(MLFLOWS))
def test_mlflow_commands_parse(command):
    import click

    with warnings.catch_warnings():  # importing mlflow's CLI warns about type hints of its own
        warnings.simplefilter("ignore")
        from mlflow.cli import cli

    words = list(command.words[1:])
    sub = cli.get_command(click.Context(cli), words[0]) if words else None
    assert sub is not None, f"{command.where}: mlflow has no command {words[:1]}"
    try:
        sub.make_context(words[0], words[1:])  # parses the options; runs nothing
    except click.ClickException as error:
        pytest.fail(f"{command.where}: {error.format_message()}")


# ---------------------------------------------------------------- python

PYTHON_COMMANDS = of_kind(PYTHONS)


@pytest.mark.parametrize("command", PYTHON_COMMANDS, ids=ids(PYTHON_COMMANDS))
def test_python_commands_name_what_exists(command):
    words = list(command.words[1:])
    if words[0] == "-c":
        compile(words[1], command.where, "exec")
    elif words[0] == "-m":
        assert importlib.util.find_spec(words[1]) is not None, f"{command.where}: no module {words[1]}"
        if words[1] == "pytest":
            files = [w.split("::")[0] for w in words[2:] if w.split("::")[0].endswith(".py")]
            missing = [f for f in files if not (ROOT / f).is_file()]
            assert not missing, f"{command.where}: no such test file {missing}"
    else:
        assert (ROOT / words[0]).is_file(), f"{command.where}: no such script {words[0]}"


# ---------------------------------------------------------------- links, paths, checkpoints, size


def paragraphs(text: str) -> list[str]:
    """The page's prose outside fenced blocks, one string per paragraph (a code span may cross lines)."""
    found, lines, inside = [], [], False
    for line in [*text.splitlines(), ""]:
        fence = re.match(r"^\s*```", line)
        if fence:
            inside = not inside
        if fence or inside or not line.strip():
            if lines:
                found.append("\n".join(lines))
            lines = []
        else:
            lines.append(line)
    return found


def headings(text: str) -> list[str]:
    return [h.group(1) for p in paragraphs(text) for h in re.finditer(r"^#{1,6}\s+(.*)$", p, re.M)]


def anchors(page: Path) -> set[str]:
    """GitHub's anchors of a page's headings."""
    found, counts = set(), defaultdict(int)
    for heading in headings(page.read_text()):
        slug = re.sub(r"[^\w\- ]", "", re.sub(r"[`*]", "", heading).strip().lower()).replace(" ", "-")
        found.add(slug if not counts[slug] else f"{slug}-{counts[slug]}")
        counts[slug] += 1
    return found


def inline_code(page: Path) -> list[str]:
    return [span for p in paragraphs(page.read_text()) for span in re.findall(r"`([^`]+)`", p)]


LINKS = [
    (page, target)
    for page in PAGES
    for paragraph in paragraphs(page.read_text())
    for target in re.findall(r"\[[^\]]*\]\(([^)\s]+)\)", re.sub(r"`[^`]*`", "", paragraph))
    if not re.match(r"^[a-z][a-z0-9+.-]*:", target)  # http:, https:, mailto:
]


@pytest.mark.parametrize("page, target", LINKS, ids=[f"{relative(p)}->{t}" for p, t in LINKS])
def test_relative_links_point_at_existing_files_and_headings(page, target):
    path, _, anchor = target.partition("#")
    file = (page.parent / path).resolve() if path else page
    assert file.exists(), f"{relative(page)}: the link {target} points at nothing"
    if anchor and file.suffix == ".md":
        assert anchor in anchors(file), f"{relative(page)}: {relative(file)} has no heading #{anchor}"


def test_the_page_reader_finds_spans_links_and_anchors(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "# Motion in 3-D\n\nSee `walkdiff/x.py` and `a\nb`, [here](other.md#few-step-students-distill).\n"
        "\n```bash\n# not a heading [no](link.md)\n```\n\n## `walkdiff evaluate`: repeats\n## Motion in 3-D\n"
    )
    assert inline_code(page) == ["walkdiff/x.py", "a\nb", "walkdiff evaluate"]
    assert anchors(page) == {"motion-in-3-d", "walkdiff-evaluate-repeats", "motion-in-3-d-1"}
    links = [re.findall(r"\]\(([^)]+)\)", p) for p in paragraphs(page.read_text())]
    assert [link for found in links for link in found] == ["other.md#few-step-students-distill"]


def test_repository_paths_and_names_in_inline_code_exist():
    """`walkdiff/x.py`, `conf/x.yaml`, `tests/x.py` exist; `walkdiff.package.module.Name` imports."""
    missing = []
    for page in PAGES:
        for span in inline_code(page):
            for word in span.split():
                word = word.strip(",.;:()")
                if re.fullmatch(r"(walkdiff|conf|tests|docs)/[\w./-]+\.(py|yaml|json|md)", word):
                    if not (ROOT / word).exists():
                        missing.append(f"{relative(page)}: {word}")
                elif re.fullmatch(r"walkdiff(\.\w+){2,}", word) and not resolves(word):
                    missing.append(f"{relative(page)}: {word}")
    assert not missing, "\n".join(missing)


def resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            if not hasattr(target, name):
                return False
            target = getattr(target, name)
        return True
    return False


def config_links() -> dict[str, set[str]]:
    """{checkpoint folder: the .ckpt links its config's RunCheckpoints keep} over conf/*.yaml."""
    from omegaconf import OmegaConf

    from walkdiff.callbacks.checkpoints import RunCheckpoint

    links = defaultdict(set)
    for path in sorted((ROOT / "conf").glob("*.yaml")):
        config = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
        for callback in (config.get("trainer") or {}).get("callbacks") or []:
            if callback.get("class_path", "").endswith("RunCheckpoint"):
                args = callback["init_args"]
                checkpoint = RunCheckpoint(**args)
                folder = args.get("dirpath") or config["trainer"]["default_root_dir"]
                links[folder].add(f"{folder}/{checkpoint.link}.ckpt")
                if args.get("save_last"):
                    links[folder].add(f"{folder}/last.ckpt")
    return links


def test_checkpoint_paths_are_where_the_configs_write_them():
    """A checkpoint under a config's folder is one of the links that config keeps; the quick start samples
    from the best checkpoint of the config `make train` trains without a GPU."""
    links = config_links()
    wrong = []
    for command in COMMANDS:
        for word in command.words:
            folder = word.rpartition("/")[0]
            if word.endswith(".ckpt") and folder in links and word not in links[folder]:
                wrong.append(f"{command.where}: {word} (the config keeps {sorted(links[folder])})")
    assert not wrong, "\n".join(wrong)

    assert "cfg=conf/xia_cpu.yaml" in MAKEFILE, "make train without a GPU trains conf/xia_cpu.yaml"
    assert "checkpoints/xia_cpu/best.ckpt" in links["checkpoints/xia_cpu"]
    readme = (ROOT / "README.md").read_text()
    quick = readme[readme.index("## Quick start") :]
    assert "make train" in quick and "walkdiff sample --ckpt checkpoints/xia_cpu/best.ckpt" in quick
    assert 'walkdiff.load("checkpoints/xia_cpu/best.ckpt")' in readme


def test_readme_is_the_front_door():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"


# Each figure the README quotes and the one place it is measured or set: (the README's words, the file,
# the words there). Both hold the same number, so one changed without the other fails below.
README_FIGURES = [
    ("after 7.4 minutes of", "docs/training.md", "the bar comes after about 7.4 minutes"),
    ("FMD 0.975x its teacher", "docs/sampling.md", "| **student** | **DDIM 1** | **146.2** "
     "(145.2, 140.7, 152.5) | **0.975** |"),
    ("at\n15,337 frames/s", "docs/sampling.md", "1 step **15,337 frames/s**"),
    ("64 gesture streams run in real time", "docs/gestures.md", "**64 measured and ~95 estimated streams in "
     "real time**"),
    ("0.15% of the\ndistance walked", "docs/walking.md", "| mean | | **0.15%** (target < 5%)"),
    ("one character at 127 frames/s", "docs/live-control.md", "| frames/s, one character (DDIM 10, eta 1) | "
     "127 (7.9 ms a frame"),
    ("32 at\n  30 frames/s", "docs/live-control.md", "| characters batched at 30 frames/s | 32 ("),
    ("the evaluator (~4 min)", "conf/evaluator_xia.yaml", "(1,800 batches, about 4 minutes)"),
    ("then the generator (~15 min)", "conf/xia_cpu.yaml", "max_steps: 1800               # the bound, in "
     "batches (~15 min on 2 quiet cores)"),
    ("`conf/xia_cpu.yaml`: 1,800 batches", "conf/xia_cpu.yaml", "max_steps: 1800 "),
    ("of its 1,800 batches", "conf/xia_cpu.yaml", "max_steps: 1800 "),
    ("from the first metrics measurement at batch 225", "conf/xia_cpu.yaml", "every_n_steps: 225"),
    ("every 450 batches", "conf/xia_cpu.yaml", "every_n_steps: 450"),
    ("Xia's 277 walks", "docs/own-data.md", "(277 clips;"),
    ("the 572 clips of Xia", "docs/benchmarks.md", "all 572 Xia clips"),
    ("4.987 against 6.090", "docs/editing.md", "| 4.987 / 6.090 |"),
]  # fmt: skip
# Numbers in the README's prose that are not measured figures: versions, and the batch of the checkpoint
# the front GIF was sampled from (a fact of that image, which no page measures).
README_NOT_FIGURES = {"3.10", "2.13.0", "2.6.6", "1.9.0", "3.17.2", "1,125"}
FIGURE = re.compile(r"(?<![\w.])(\d{1,3}(?:,\d{3})+|\d+\.\d+(?:\.\d+)?)(?![\w.]*\d)")


def figure_numbers(text: str) -> set[str]:
    """The decimal and thousands-separated numbers of a text (what a measured figure looks like)."""
    return set(FIGURE.findall(text))


def same_number(a: str, b: str) -> bool:
    return a.replace(",", "") == b.replace(",", "")


@pytest.mark.parametrize(("quoted", "source", "held"), README_FIGURES, ids=[f[0] for f in README_FIGURES])
def test_readme_figures_are_the_ones_their_pages_hold(quoted, source, held):
    readme = (ROOT / "README.md").read_text()
    assert quoted in readme, f"README.md no longer says {quoted!r}: update README_FIGURES"
    assert held in (ROOT / source).read_text(), f"{source} no longer says {held!r}"
    numbers = re.findall(r"\d[\d,.]*\d|\d", quoted)
    assert numbers and all(
        any(same_number(n, m) for m in re.findall(r"\d[\d,.]*\d|\d", held)) for n in numbers
    ), f"README.md says {quoted!r}; {source} holds {held!r}"


def test_every_figure_in_the_readme_has_its_source():
    """A new figure in the README comes with the page that measures it (README_FIGURES)."""
    readme = re.sub(r"```.*?```", "", (ROOT / "README.md").read_text(), flags=re.S)
    listed = set().union(*(figure_numbers(q) | set(re.findall(r"\d+", q)) for q, _, _ in README_FIGURES))
    loose = sorted(figure_numbers(readme) - listed - README_NOT_FIGURES)
    assert not loose, f"README.md quotes {loose} with no source in README_FIGURES"
