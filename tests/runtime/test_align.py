"""Prompt alignment: the rules on a table of free-form prompts, the LLM backend against a
local fake server (good, slow, malformed, failing answers), and aligned generation."""

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from mogo.align import AlignedStep, Alignment, RuleAligner, edit_distance, plain_words
from mogo.align_words import caption_phrases, spoken_number, spoken_numbers
from mogo.cli import main
from mogo.generator import MotionGenerator
from mogo.llm_align import LLMAligner
from mogo.motion.skeleton import MAX_SECONDS


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.fixture(scope="module")
def rules(generator):
    return RuleAligner(generator.vocabulary())


WALK, WAVE_RIGHT = "a person walks forward.", "a person waves with the right hand."
RULES_TABLE = [
    # plain captions and imperatives
    ("walk forward", [WALK]),
    ("Walk forward.", [WALK]),
    ("a person walks forward, then waves with the right hand", [WALK, WAVE_RIGHT]),
    (
        "a man walks backward slowly and then turns left. after that, he claps his hands four "
        "times.",
        [
            "a person walks backward slowly.",
            "a person turns left.",
            "a person claps his hands four times.",
        ],
    ),
    ("someone sidesteps to the right", ["a person sidesteps to the right."]),
    ("take a seat", ["a person takes a seat."]),
    ("jump forward", ["a person jumps forward."]),
    # requests, subjects and filler
    ("make the guy do a cartwheel and then sit", ["a person does a cartwheel.", "a person sits."]),
    (
        "I want him to stroll ahead and after that wave 3 times",
        ["a person strolls ahead.", "a person waves three times."],
    ),
    (
        "can you make someone sprint forward; then crouch down twice",
        ["a person sprints forward.", "a person crouches down twice."],
    ),
    (
        "could you have somebody stroll ahead and afterwards wave their right arm",
        ["a person strolls ahead.", "a person waves their right arm."],
    ),
    (
        "so um like the character should kinda run fast and then maybe kick with the left leg "
        "and finally bow",
        ["a person runs fast.", "a person kicks with the left leg.", "a person bows."],
    ),
    (
        "I would like to see an animation of a person running quickly forward then doing squats",
        ["a person runs quickly forward.", "a person does squats."],
    ),
    ("she stretches, then sits", ["a person stretches.", "a person sits."]),
    (
        "he raises both arms above his head before doing a bow",
        ["a person raises both arms above his head.", "a person does a bow."],
    ),
    # sequence words
    ("jump 3 times before sitting down", ["a person jumps three times.", "a person sits down."]),
    (
        "after walking forward, wave with the left hand",
        [WALK, "a person waves with the left hand."],
    ),
    ("wave with the right hand after walking forward", [WALK, WAVE_RIGHT]),
    ("walking in a circle and then waving", ["a person walks in a circle.", "a person waves."]),
    (
        "first jog backwards, next turn around, finally sit down",
        ["a person jogs backwards.", "a person turns around.", "a person sits down."],
    ),
    ("walk, jump, sit down", ["a person walks.", "a person jumps.", "a person sits down."]),
    ("walk; jump; sit", ["a person walks.", "a person jumps.", "a person sits."]),
    (
        "hop on the spot 2 times, followed by a bow",
        ["a person hops on the spot twice.", "a person takes a bow."],
    ),
    ("walk forward and when it is finished wave", [WALK, "a person waves."]),
    (
        "kick out the right leg and once that's done, hop in place once",
        ["a person kicks out the right leg.", "a person hops in place once."],
    ),
    (
        "stand still for 2 seconds then walk backwards",
        ["a person stands still for two seconds.", "a person walks backwards."],
    ),
    # at the same time: one step
    ("wave while walking forward", ["a person waves while walking forward."]),
    ("the person jogs in a circle as he claps", ["a person jogs in a circle as he claps."]),
    (
        "squat down and stand back up three times",
        ["a person squats down and stands back up three times."],
    ),
    # synonyms onto the vocabulary
    (
        "make her march to the left and then punch twice with the right fist",
        ["a person walks to the left.", "a person punches twice with the right fist."],
    ),
    ("the dude hurries forward and then applauds", ["a person runs forward.", "a person claps."]),
    (
        "spin around counter-clockwise then stop",
        ["a person spins around counterclockwise.", "a person stands."],
    ),
    ("a woman twirls to the left", ["a person spins to the left."]),
    ("star jumps x4", ["a person does jumping jacks four times."]),
    # numbers
    ("wave 3 times", ["a person waves three times."]),
    ("turn 90 degrees to the left", ["a person turns ninety degrees to the left."]),
    ("clap 15 times", ["a person claps fifteen times."]),
    ("clap twice", ["a person claps twice."]),
    ("punch one time with your left fist", ["a person punches once with their left fist."]),
    ("kick with the right leg 2x", ["a person kicks with the right leg twice."]),
    (
        "do 5 jumping jacks then stand still for 3 seconds",
        ["a person does five jumping jacks.", "a person stands still for three seconds."],
    ),
    # typos, shouting, spacing
    ("the person wlaks fowrard then sqauts", [WALK, "a person squats."]),
    ("plese make her stretch then bow politly", ["a person stretches.", "a person bows politely."]),
    ("SIT DOWN!!! then WAVE", ["a person sits down.", "a person waves."]),
    ("  walk   forward   ,   then    turn   right  ", [WALK, "a person turns right."]),
    # other languages and letters
    ("Café: la personne marche 前进 then wave", ["a person walks.", "a person waves."]),
    ("Él camina hacia adelante then jumps", ["a person jumps."]),
    ("ｗａｖｅ　ｔｗｉｃｅ", ["a person waves twice."]),
    # rambling
    (
        "ok so first you walk forward a bit, like maybe four steps, and then you turn to the "
        "left, and after that you just wait there for a moment, and then finally you wave with "
        "both hands to say goodbye",
        [
            "a person walks forward four steps.",
            "a person turns to the left.",
            "a person waits there for a moment.",
            "a person waves with both hands to say hello.",
        ],
    ),
]


@pytest.mark.parametrize("text,expected", RULES_TABLE, ids=[t[:40] for t, _ in RULES_TABLE])
def test_rules_table(rules, text, expected):
    alignment = rules.align(text)
    assert [step.prompt for step in alignment.steps] == expected
    assert alignment.source == "rules"
    assert all(1.0 <= step.seconds <= MAX_SECONDS for step in alignment.steps)


def test_the_table_is_large_enough():
    assert len(RULES_TABLE) >= 40


def test_durations_follow_the_primitive_and_the_count(rules):
    seconds = {
        text: rules.align(text).steps[0].seconds
        for text in (
            "walk forward",
            "wave",
            "jump",
            "jump four times",
            "sit down",
            "stand still for 5 seconds",
            "clap 60 times",
        )
    }
    assert seconds["jump"] < seconds["wave"] < seconds["walk forward"] < seconds["sit down"]
    assert seconds["jump four times"] > seconds["jump"] + 1.5
    assert seconds["stand still for 5 seconds"] == 5.0
    assert seconds["clap 60 times"] == MAX_SECONDS  # clamped to what one step of the model holds


def test_unknown_and_ignored_words_are_reported(rules):
    note = rules.align("make the guy do a cartwheel and then sit").note
    assert note == "the model does not know cartwheel (kept as written)"
    assert "ignored 'cafe'" in rules.align("Café: then wave").note
    assert rules.align("walk forward").note is None


@pytest.mark.parametrize(
    "text,message",
    [
        ("", "no usable words"),
        ("   ", "no usable words"),
        ("!!! ...", "no usable words"),
        ("日本語のテキスト", "no usable words"),
        ("please", "no motion"),
        ("hello world", "no motion"),
        ("can you", "no motion"),
    ],
)
def test_unusable_prompts_raise_a_clear_error(rules, text, message):
    with pytest.raises(ValueError, match=message):
        rules.align(text)


def test_without_a_vocabulary_words_are_kept():
    steps = RuleAligner().align("the guy marches forward then does a pirouette").steps
    assert [s.prompt for s in steps] == ["a person marches forward.", "a person does a pirouette."]


def test_helpers():
    assert plain_words("Ça VA, naïve—Straße 3x") == ["ca", "va", "naive", "strasse", "3x"]
    assert edit_distance("walk", "wlak", 2) == 1 and edit_distance("walk", "squat", 2) == 3
    alignment = Alignment((AlignedStep("a", 3.0), AlignedStep("b", 1.0)), "rules")
    assert [s.seconds for s in alignment.scaled(8).steps] == [6.0, 2.0]
    assert alignment.describe() == 'steps (rules): 3.0 s "a" | 1.0 s "b"'


# -- the LLM backend against a fake local server ----------------------------------------------
GOOD_ANSWER = (
    'The person strolls, then waves. Two steps: {"not": "this one"} is a thought.\n'
    '{"prompt": "a person strolls forward, then waves.", "steps": ['
    '{"prompt": "a person strolls forward.", "seconds": 3.5}, '
    '{"prompt": "a person waves with the right hand.", "seconds": 2}]}'
)


class FakeServer:
    """A chat-completions endpoint answering what the test sets; records the requests. With
    `hold` set it answers once the test is over (or after 30 s, so that a client ignoring its
    timeout fails instead of hanging): far later than the timeout the test gives."""

    def __init__(self):
        self.status, self.content, self.hold, self.raw = 200, GOOD_ANSWER, False, None
        self.requests = []
        self.released = threading.Event()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                length = int(self.headers["Content-Length"])
                server.requests.append(
                    (self.path, dict(self.headers), json.loads(self.rfile.read(length)))
                )
                if server.hold:
                    server.released.wait(30)
                reply = server.raw or json.dumps(
                    {"choices": [{"message": {"role": "assistant", "content": server.content}}]}
                )
                self.send_response(server.status)
                self.send_header("Content-Type", "application/json")
                self.end_headers()
                self.wfile.write(reply.encode())

            def log_message(self, *args):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True).start()


@pytest.fixture
def server():
    fake = FakeServer()
    yield fake
    fake.released.set()
    fake.httpd.shutdown()
    fake.httpd.server_close()


PROMPT = "have somebody stroll ahead and afterwards wave"


def test_llm_good_answer_after_thinking(server):
    alignment = LLMAligner(server.url, model="tiny", api_key="secret").align(PROMPT)
    assert alignment == Alignment(
        (
            AlignedStep("a person strolls forward.", 3.5),
            AlignedStep("a person waves with the right hand.", 2.0),
        ),
        "llm",
    )
    path, headers, body = server.requests[0]
    assert path == "/v1/chat/completions" and headers["Authorization"] == "Bearer secret"
    assert body["model"] == "tiny" and body["temperature"] == 0
    assert (
        body["messages"][0]["role"] == "system" and "step by step" in body["messages"][0]["content"]
    )
    assert body["messages"][-1] == {"role": "user", "content": PROMPT}


def test_llm_configured_by_environment(server, monkeypatch):
    monkeypatch.setenv("MOGO_LLM_URL", server.url)
    monkeypatch.setenv("MOGO_LLM_MODEL", "from-env")
    monkeypatch.setenv("MOGO_LLM_API_KEY", "env-key")
    assert LLMAligner().align(PROMPT).source == "llm"
    _, headers, body = server.requests[0]
    assert body["model"] == "from-env" and headers["Authorization"] == "Bearer env-key"


def test_llm_without_url_or_key(server, monkeypatch):
    monkeypatch.delenv("MOGO_LLM_URL", raising=False)
    monkeypatch.delenv("MOGO_LLM_API_KEY", raising=False)
    with pytest.raises(ValueError, match="MOGO_LLM_URL"):
        LLMAligner()
    LLMAligner(server.url).align(PROMPT)
    assert "Authorization" not in server.requests[0][1]


@pytest.mark.parametrize(
    "setup,note",
    [
        (dict(hold=True), "the LLM did not answer within 0.5 s; used the rules"),
        (dict(status=500), "the LLM server answered HTTP 500; used the rules"),
        (dict(content="Sure! The person walks, then waves."), "the LLM answer was not valid JSON"),
        (
            dict(
                content='{"prompt": "a person walks.", "steps": [{"prompt": "a person walks.", '
                '"seconds": 3'
            ),
            "the LLM answer was not valid JSON",
        ),
        (dict(raw="<html>bad gateway</html>"), "the LLM server's reply was not usable"),
        (dict(raw='{"choices": []}'), "no choices[0].message.content"),
        (dict(content='{"prompt": "x", "steps": []}'), "has 0 steps; 1 to 8 are allowed"),
        (
            dict(
                content='{"prompt": "x", "steps": [{"prompt": "a person walks.", "seconds": 99}]}'
            ),
            "step 1 has seconds 99",
        ),
        (
            dict(content='{"prompt": "x", "steps": [{"prompt": " ", "seconds": 2}]}'),
            "step 1 has no prompt text",
        ),
        (dict(content='{"steps": "walk"}'), "does not match the schema"),
    ],
    ids=[
        "timeout",
        "http-500",
        "no-json",
        "broken-json",
        "not-json-reply",
        "no-choices",
        "no-steps",
        "seconds-out-of-range",
        "empty-step",
        "wrong-schema",
    ],
)
def test_llm_failures_fall_back_to_the_rules(server, rules, setup, note):
    """Only the held server may time out: the others get a timeout no busy machine reaches."""
    for name, value in setup.items():
        setattr(server, name, value)
    timeout = 0.5 if server.hold else 60
    alignment = LLMAligner(server.url, timeout=timeout, fallback=rules).align(PROMPT)
    assert alignment.source == "rules" and note in alignment.note
    assert alignment.steps == rules.align(PROMPT).steps


def test_llm_unreachable_server_falls_back(rules):
    alignment = LLMAligner("http://127.0.0.1:9/v1", timeout=30, fallback=rules).align(PROMPT)
    assert alignment.source == "rules"
    assert alignment.note.startswith("cannot reach the LLM server at http://127.0.0.1:9/v1")


# -- aligned generation --------------------------------------------------------------------------
def test_generate_aligned_plays_the_steps_as_one_motion(generator, tmp_path):
    motion = generator.generate(
        "make the guy walk forward and then wave twice", seconds=3, seed=0, align=True
    )
    steps = motion.alignment.steps
    assert [s.prompt for s in steps] == [WALK, "a person waves twice."]
    assert sum(s.seconds for s in steps) == pytest.approx(3.0)
    assert [text for _, text in motion.prompts] == [s.prompt for s in steps]
    assert motion.prompts[1][0] == round(steps[0].seconds * generator.fps)
    assert len(motion.joints) == 60
    document = json.loads(motion.save_json(tmp_path / "m.json").read_text())
    assert document["alignment"]["source"] == "rules"
    assert [s["prompt"] for s in document["alignment"]["steps"]] == [s.prompt for s in steps]
    again = generator.generate(
        "make the guy walk forward and then wave twice",
        seconds=3,
        seed=0,
        align=RuleAligner(generator.vocabulary()),
    )
    assert (again.tokens == motion.tokens).all()


def test_generate_aligned_list_and_default(generator):
    first, second = generator.generate_batch(["jump twice", "sit down"], seed=1, align=True)
    assert first.alignment.steps[0].prompt == "a person jumps twice."
    assert len(first.joints) == round(first.alignment.seconds * generator.fps)
    assert second.prompts == [(0, "a person sits down.")]
    assert generator.generate("walk", seconds=1, seed=0).alignment is None
    with pytest.raises(ValueError, match="align must be True, False or a PromptAligner"):
        generator.generate("walk", seconds=1, align="rules")


# -- the command line ----------------------------------------------------------------------------
def test_cli_align_rules_prints_and_stores_the_steps(tmp_path, capsys):
    assert (
        main(
            [
                "generate",
                "make the guy do a cartwheel and then sit",
                "--align",
                "rules",
                "--seconds",
                "3",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--name",
                "m",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == (
        'steps (rules): 1.3 s "a person does a cartwheel." | 1.7 s "a person sits."'
    )
    assert printed[1] == "note: the model does not know cartwheel (kept as written)"
    document = json.loads((tmp_path / "m.json").read_text())
    assert [p["text"] for p in document["prompts"]] == [
        "a person does a cartwheel.",
        "a person sits.",
    ]


def test_cli_align_llm_falls_back_and_says_why(server, tmp_path, capsys, monkeypatch):
    server.status = 500
    monkeypatch.setenv("MOGO_LLM_URL", server.url)
    assert (
        main(
            [
                "generate",
                "walk forward then wave",
                "--align",
                "llm",
                "--seconds",
                "2",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "steps (rules): " in printed
    assert "note: the LLM server answered HTTP 500; used the rules" in printed
    assert main(["generate", "--prompts-file", str(tmp_path / "x"), "--align", "rules"]) == 2
    assert "--align rewrites one prompt" in capsys.readouterr().err


def test_numbers_are_spelt_as_the_captions_spell_them():
    assert [spoken_number(n) for n in (0, 13, 20, 45, 99, 100, 135, 360, 999, 1000, -1)] == [
        "zero",
        "thirteen",
        "twenty",
        "forty-five",
        "ninety-nine",
        "a hundred",
        "a hundred and thirty-five",
        "three hundred and sixty",
        "nine hundred and ninety-nine",
        "1000",
        "-1",
    ]
    assert spoken_numbers("turn 90 degrees, clap 2 times, wave 1 time, jump 3 times") == (
        "turn ninety degrees, clap twice, wave once, jump three times"
    )
    for kept in ("walk for 2.5 seconds", "jump 12x", "the v2 model", "1,000 steps"):
        assert spoken_numbers(kept) == kept
    assert caption_phrases("do 4 Star Jumps, then spin counter clockwise") == (
        "do 4 jumping jacks, then spin counterclockwise"
    )
