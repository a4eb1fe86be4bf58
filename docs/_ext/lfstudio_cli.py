"""``{lfstudio-cli}``: the command-line reference, generated from lfstudio's own parsers.

Every command (and sub-command) gets a section with its description, its usage line, every option
grouped as ``--help`` groups them, with the help text that ``--help`` prints (``%(default)s`` filled
in), and its epilog. Nothing is written twice: a new option appears here at the next build."""

from __future__ import annotations

import argparse

from docutils import nodes
from sphinx.util.docutils import SphinxDirective


def _expand(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    formatter = parser._get_formatter()
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    try:
        return " ".join(formatter._expand_help(action).split())
    except (KeyError, TypeError, ValueError):
        return " ".join(action.help.split())


def _invocation(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    return parser._get_formatter()._format_action_invocation(action)


def _section(title: str, ids: str) -> nodes.section:
    section = nodes.section(ids=[nodes.make_id(ids)], names=[nodes.fully_normalize_name(ids)])
    section += nodes.title(text=title)
    return section


def command_section(parser: argparse.ArgumentParser, name: str) -> nodes.section:
    """The section of one command (``name``: "lfstudio scan"), its sub-commands nested inside."""
    section = _section(name, name.replace(" ", "-"))
    if parser.description:
        section += nodes.paragraph(text=" ".join(parser.description.split()))
    usage = parser.format_usage().strip()
    section += nodes.literal_block(usage, usage)
    subcommands: list[tuple[str, argparse.ArgumentParser]] = []
    for group in parser._action_groups:
        actions = [a for a in group._group_actions if a.help != argparse.SUPPRESS]
        rows = nodes.definition_list()
        for action in actions:
            if isinstance(action, argparse._SubParsersAction):
                subcommands += [(n, p) for n, p in action.choices.items() if n not in {s for s, _ in subcommands}]
                continue
            item = nodes.definition_list_item()
            term = nodes.term()
            term += nodes.literal(text=_invocation(parser, action))
            item += term
            definition = nodes.definition()
            text = _expand(parser, action)
            if action.choices is not None and not isinstance(action.choices, dict):
                text += (" " if text else "") + "Choices: " + ", ".join(map(str, action.choices)) + "."
            definition += nodes.paragraph(text=text or "(no description)")
            item += definition
            rows += item
        if len(rows):
            title = group.title or "options"
            section += nodes.rubric(text=title[:1].upper() + title[1:])
            section += rows
    if parser.epilog:
        section += nodes.paragraph(text=" ".join(parser.epilog.split()))
    for sub_name, sub in subcommands:
        section += command_section(sub, f"{name} {sub_name}")
    return section


class LfstudioCli(SphinxDirective):
    """Every command of ``lfstudio`` as a section each, in the order ``lfstudio --help`` lists them."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from lfstudio.cli import build_parser

        parser = build_parser()
        top = command_section(parser, "lfstudio")
        out: list[nodes.Node] = list(top.children[1:])          # the top command's text, not its title
        moved = [c for c in out if isinstance(c, nodes.section)]
        return [c for c in out if not isinstance(c, nodes.section)] + moved


def params_table(cls) -> nodes.table:
    """A table of a described dataclass's keys (``lfstudio.numbers.described``): key, what it is,
    valid values, default."""
    import dataclasses

    from lfstudio.numbers import params_of

    defaults = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            defaults[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            defaults[f.name] = f.default_factory()
    table = nodes.table()
    group = nodes.tgroup(cols=4)
    table += group
    for width in (20, 40, 25, 15):
        group += nodes.colspec(colwidth=width)
    head = nodes.thead()
    group += head
    body = nodes.tbody()
    group += body

    def row(cells, into, literal_first=False):
        r = nodes.row()
        for i, text in enumerate(cells):
            entry = nodes.entry()
            para = nodes.paragraph()
            para += nodes.literal(text=text) if literal_first and i == 0 else nodes.Text(text)
            entry += para
            r += entry
        into += r

    row(["key", "what it is", "valid values", "default"], head)
    for name, param in params_of(cls).items():
        what = " ".join(p for p in (param.label, param.tip) if p)
        default = defaults.get(name, "(required)")
        if isinstance(default, (list, tuple)):
            default = ", ".join(map(str, default))
        row([name, what, param.valid(), str(default)], body, literal_first=True)
    return table


class LfstudioParams(SphinxDirective):
    """``{lfstudio-params} module:Class``: the keys of a file table described on a dataclass."""

    required_arguments = 1
    has_content = False

    def run(self) -> list[nodes.Node]:
        import importlib

        module, _, name = self.arguments[0].partition(":")
        return [params_table(getattr(importlib.import_module(module), name))]


def setup(app):
    app.add_directive("lfstudio-cli", LfstudioCli)
    app.add_directive("lfstudio-params", LfstudioParams)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
