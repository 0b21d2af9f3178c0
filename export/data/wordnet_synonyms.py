"""The WordNet tables: the verb table of the rule aligner (runtime/align_wordnet.py) and the
people and adjectives the text adapter's training puts in its captions' place
(export/data/wordnet_people.py), generated from the WordNet 3.0 database files (Debian's
wordnet-base puts them in /usr/share/wordnet):

    python -m mogo.export.data.wordnet_synonyms [--wordnet /usr/share/wordnet] \
        --out runtime/align_wordnet.py --people-out export/data/wordnet_people.py

A verb maps to a primitive when its first sense of the kind the heads are (WordNet's
lexicographer files: motion, body, contact, communication; "hike" is first "increase", then
"walk a long way") is one of the primitive's head senses below or a troponym of one ("plod:
walk heavily", "vault: jump across"), down to the head's depth. Only that first sense
counts, so a word whose usual meaning is another stays out ("crouch" is first "stoop", not
"squat"). Verbs the hand-written lists (mogo.align_words.VERBS) already have are left to
them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

# primitive -> head senses (lemma, WordNet sense number) and the troponym depth followed
HEADS = {
    "walk": ([("walk", 1)], 2),
    "jog": ([("jog", 3), ("jog", 4)], 1),
    "run": ([("run", 1), ("race", 1)], 2),
    "jump": ([("jump", 1), ("hop", 1), ("vault", 2)], 2),
    "turn": ([("turn", 1)], 0),
    "spin": ([("spin", 1)], 1),
    "squat": ([("squat", 1)], 0),
    "sit": ([("sit", 1), ("sit", 3)], 1),
    "bow": ([("bow", 1), ("bow", 3)], 1),
    "wave": ([("wave", 1)], 0),
    "raise_arms": ([("raise", 2)], 0),
    "clap": ([("clap", 3), ("clap", 4)], 1),
    "punch": ([("punch", 1)], 1),
    "kick": ([("kick", 1), ("kick", 3), ("kick", 4)], 1),
    "stretch": ([("stretch", 2)], 0),
    "idle": ([("stand", 1)], 0),
}
NOTICE = """WordNet Release 3.0. This software and database is being provided to you, the LICENSEE,
by Princeton University under the following license. By obtaining, using and/or copying
this software and database, you agree that you have read, understood, and will comply with
these terms and conditions.: Permission to use, copy, modify and distribute this software
and database and its documentation for any purpose and without fee or royalty is hereby
granted, provided that you agree to comply with the following copyright notice and
statements, including the disclaimer, and that the same appear on ALL copies of the
software, database and documentation, including modifications that you make for internal
use or for distribution. WordNet 3.0 Copyright 2006 by Princeton University. All rights
reserved. THIS SOFTWARE AND DATABASE IS PROVIDED "AS IS" AND PRINCETON UNIVERSITY MAKES NO
REPRESENTATIONS OR WARRANTIES, EXPRESS OR IMPLIED. BY WAY OF EXAMPLE, BUT NOT LIMITATION,
PRINCETON UNIVERSITY MAKES NO REPRESENTATIONS OR WARRANTIES OF MERCHANT- ABILITY OR FITNESS
FOR ANY PARTICULAR PURPOSE OR THAT THE USE OF THE LICENSED SOFTWARE, DATABASE OR
DOCUMENTATION WILL NOT INFRINGE ANY THIRD PARTY PATENTS, COPYRIGHTS, TRADEMARKS OR OTHER
RIGHTS. The name of Princeton University or Princeton may not be used in advertising or
publicity pertaining to distribution of the software and/or database. Title to copyright
in this software, database and any associated documentation shall at all times remain with
Princeton University and LICENSEE agrees to preserve same."""


def read_index(wordnet: Path, pos: str) -> dict[str, tuple[list[str], int]]:
    """lemma -> (its synset offsets in sense order, how often its senses are tagged in
    WordNet's sense-tagged corpus), for one part of speech ("verb", "noun", "adj")."""
    senses = {}
    for line in (wordnet / f"index.{pos}").read_text().splitlines():
        if not line.startswith(" "):
            parts = line.split()
            count = int(parts[2])  # lemma pos synsets pointers [symbols] senses tagged offsets
            senses[parts[0]] = (parts[-count:], int(parts[-count - 1]))
    return senses


def read_synsets(wordnet: Path, pos: str) -> dict[str, tuple[list[str], list[str], str]]:
    """offset -> (its words as written, the offsets of its hyponyms (troponyms, for verbs),
    its lexicographer file), for one part of speech ("verb", "noun")."""
    synsets = {}
    for line in (wordnet / f"data.{pos}").read_text().splitlines():
        if not line.startswith(" "):
            parts = line.split("|")[0].split()
            count = int(parts[3], 16)
            k = 4 + 2 * count
            pointers = [parts[k + 1 + 4 * i : k + 5 + 4 * i] for i in range(int(parts[k]))]
            synsets[parts[0]] = (
                [parts[4 + 2 * i] for i in range(count)],
                [p[1] for p in pointers if p[0] == "~" and p[2] == pos[0]],
                parts[1],
            )
    return synsets


def verb_table(wordnet: Path, hand_written: set[str]) -> dict[str, list[str]]:
    """primitive -> the single-word verbs whose first sense falls under its heads."""
    senses = {lemma: offsets for lemma, (offsets, _) in read_index(wordnet, "verb").items()}
    synsets = read_synsets(wordnet, "verb")
    depth_of: dict[str, dict[str, int]] = {}  # offset -> primitive -> depth
    kinds = set()
    for primitive, (heads, depth) in HEADS.items():
        frontier = [senses[lemma][number - 1] for lemma, number in heads]
        kinds |= {synsets[offset][2] for offset in frontier}
        for level in range(depth + 1):
            for offset in frontier:
                depth_of.setdefault(offset, {}).setdefault(primitive, level)
            frontier = [t for offset in frontier for t in synsets[offset][1]]
    table: dict[str, list[str]] = {primitive: [] for primitive in HEADS}
    for lemma, offsets in sorted(senses.items()):
        first = next((o for o in offsets if synsets[o][2] in kinds), None)
        if not lemma.isalpha() or lemma in hand_written or first not in depth_of:
            continue
        found = depth_of[first]
        closest = min(found.values())
        primitives = [p for p, level in found.items() if level == closest]
        if len(primitives) == 1:  # two primitives equally close: ambiguous, left out
            table[primitives[0]].append(lemma)
    return {primitive: verbs for primitive, verbs in table.items() if verbs}


def people(wordnet: Path) -> tuple[list[str], list[str]]:
    """(every one-word kind of person, WordNet's hyponyms of person.n.01 at any depth, that
    is lower case and tagged at least once in WordNet's sense-tagged corpus: "dancer",
    "soldier", "accountant"; the adjectives tagged more than twice: "old", "tired"). Rare
    and proper nouns are left out."""
    synsets, nouns = read_synsets(wordnet, "noun"), read_index(wordnet, "noun")
    seen, frontier = set(), [nouns["person"][0][0]]
    while frontier:
        offset = frontier.pop()
        if offset not in seen:
            seen.add(offset)
            frontier += synsets[offset][1]
    kinds = {w for offset in seen for w in synsets[offset][0]}
    return (
        sorted(w for w in kinds if w.isalpha() and w.islower() and nouns.get(w, (0, 0))[1]),
        sorted(
            w for w, (_, tagged) in read_index(wordnet, "adj").items() if w.isalpha() and tagged > 2
        ),
    )


def render_people(nouns: list[str], adjectives: list[str], command: str) -> str:
    notice = "\n".join("# " + line for line in NOTICE.splitlines())
    return (
        f'"""Kinds of people and adjectives, from WordNet 3.0 (generated: do not edit); the '
        f"text\nadapter's training puts them in its captions' subjects. Regenerate with\n"
        f"`{command}`\n(mogo.export.data.wordnet_synonyms says how)."
        f'"""\n{notice}\n\nPEOPLE = {tuple(nouns)!r}\nADJECTIVES = {tuple(adjectives)!r}\n'
    )


def render(table: dict[str, list[str]], command: str) -> str:
    notice = "\n".join("# " + line for line in NOTICE.splitlines())
    rows = "\n".join(f"    {primitive!r}: {tuple(verbs)!r}," for primitive, verbs in table.items())
    return (
        f'"""Verbs by the primitive they ask for, from WordNet 3.0 (generated: do not edit).\n'
        f"Regenerate with\n`{command}`\n(mogo.export.data.wordnet_synonyms says how)."
        f'"""\n{notice}\n\nWORDNET_VERBS = {{\n{rows}\n}}\n'
    )


def main() -> None:
    from mogo.align_words import VERBS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wordnet", type=Path, default=Path("/usr/share/wordnet"))
    parser.add_argument("--out", type=Path, required=True, help="the verb table")
    parser.add_argument("--people-out", type=Path, required=True, help="people and adjectives")
    args = parser.parse_args()
    hand_written = {verb for verbs in VERBS.values() for verb in verbs}
    table = verb_table(args.wordnet, hand_written)
    command = (
        "python -m mogo.export.data.wordnet_synonyms --out runtime/align_wordnet.py \\\n"
        "    --people-out export/data/wordnet_people.py"
    )
    nouns, adjectives = people(args.wordnet)
    args.out.write_text(render(table, command))
    args.people_out.write_text(render_people(nouns, adjectives, command))
    print(
        f"wrote {args.out}: {sum(map(len, table.values()))} verbs; {args.people_out}: "
        f"{len(nouns)} people, {len(adjectives)} adjectives"
    )


if __name__ == "__main__":
    main()
