"""Prompt alignment by a language model behind an OpenAI-compatible chat-completions server
(llama.cpp server, Ollama, vLLM, ...), standard library only.

    aligner = LLMAligner("http://localhost:8080/v1", model="qwen2.5-7b-instruct")
    aligner.align("could you have somebody stroll ahead and afterwards wave")

The model thinks step by step (the paper's chain of thought), then answers with one JSON
object; the answer is checked against a schema. Whatever goes wrong (timeout, refused
connection, HTTP error, no JSON, a wrong schema) the rules answer instead, and
Alignment.note says why.
"""

from __future__ import annotations

import http.client
import json
import os
import socket
import threading
import urllib.error
import urllib.request
from numbers import Real

from mogo.align import AlignedStep, Alignment, PromptAligner, RuleAligner

MAX_STEPS = 8
MAX_TIMEOUT = 3600.0  # seconds; an aligner waiting longer has hung
MAX_REPLY_BYTES = 1 << 20  # a chat reply is a few KB; a larger one is refused unread
MAX_ANSWER_CHARS = 16384  # the answer's JSON is looked for in the reply's last characters
STEP_SECONDS = (0.5, 30.0)

SYSTEM_PROMPT = """\
You turn a request for a human motion into the captions a text-to-motion model was trained on.
The training captions look like this:
  "a person walks forward slowly."
  "someone waves with the right hand twice."
  "a person squats down and stands back up three times."
  "the person turns ninety degrees to the left."
  "a person does four jumping jacks."
Rules:
1. Each step is one atomic action, written as "a person <verb in 3rd person> ...", in plain
   lowercase English with the words of such captions, ending with a period.
2. Split a composite request into its steps in the order they happen ("then", "after that",
   "before", "after ..." all give an order). Actions done at the same time ("while", "as")
   stay one step.
3. Keep directions, sides (left/right), speeds and counts ("three times", "twice").
4. Give each step a duration in seconds: walking or running 3-4, a wave about 2, jumps about
   1 per repetition, sitting down about 4, a turn or a bow about 2.
Think step by step first: say who does what, in which order, and how long each part takes.
Then, on the last lines, give only this JSON object:
{"prompt": "<all steps as one caption>", "steps": [{"prompt": "<step>", "seconds": <number>}]}"""

EXAMPLES = (
    (
        "make the guy stroll ahead and after that wave 3 times",
        "The person walks forward at a slow pace, then waves; the wave is repeated three times. "
        "Two steps: walking about 3.5 s, three waves about 3 s.\n"
        '{"prompt": "a person strolls forward, then waves three times.", "steps": ['
        '{"prompt": "a person strolls forward.", "seconds": 3.5}, '
        '{"prompt": "a person waves three times.", "seconds": 3.0}]}',
    ),
    (
        "jump twice before sitting down, I want him to wave while he sits",
        "'Before' orders the actions: the jumps come first, then sitting down. The wave happens "
        "while sitting, so it stays in the sitting step. Two jumps about 2 s, sitting while "
        "waving about 4 s.\n"
        '{"prompt": "a person jumps twice, then sits down while waving.", "steps": ['
        '{"prompt": "a person jumps twice.", "seconds": 2.0}, '
        '{"prompt": "a person sits down while waving.", "seconds": 4.0}]}',
    ),
    (
        "after a quick jog to the left she does a full spin and bows",
        "'After' puts the jog first. Then a spin, then a bow: three steps. Jog about 3 s, spin "
        "about 2 s, bow about 2 s.\n"
        '{"prompt": "a person jogs quickly to the left, then spins around, then bows.", '
        '"steps": [{"prompt": "a person jogs quickly to the left.", "seconds": 3.0}, '
        '{"prompt": "a person does a full spin.", "seconds": 2.0}, '
        '{"prompt": "a person bows.", "seconds": 2.0}]}',
    ),
)


class LLMAligner(PromptAligner):
    """url: the server's base URL ("http://localhost:8080/v1"; env MOGO_LLM_URL); model:
    the model name the server expects (env MOGO_LLM_MODEL); api_key: sent as a bearer
    token (env MOGO_LLM_API_KEY; local servers need none), to that server only: a redirect
    is not followed. timeout: seconds for the whole exchange, the reply read to its end."""

    def __init__(
        self,
        url: str | None = None,
        model: str | None = None,
        api_key: str | None = None,
        timeout: float = 10.0,
        fallback: PromptAligner | None = None,
    ):
        self.url = url or os.environ.get("MOGO_LLM_URL")
        if not self.url:
            raise ValueError(
                "the LLM aligner needs a server URL: pass url= (--llm-url) or set "
                "MOGO_LLM_URL, e.g. http://localhost:8080/v1"
            )
        self.model = model or os.environ.get("MOGO_LLM_MODEL") or "default"
        self.api_key = api_key or os.environ.get("MOGO_LLM_API_KEY")
        if isinstance(timeout, bool) or not isinstance(timeout, Real):
            raise TypeError(f"timeout must be a number of seconds, got {type(timeout).__name__}")
        if not 0 < timeout <= MAX_TIMEOUT:  # nan, inf and 1e300 were a traceback or a wrong note
            raise ValueError(
                f"the LLM timeout must be a positive number of seconds up to "
                f"{MAX_TIMEOUT:.0f}, got {timeout:g}"
            )
        self.timeout = timeout
        self.fallback = fallback or RuleAligner()

    def align(self, text: str) -> Alignment:
        try:
            content = self._ask(text)
        except TimeoutError:
            return self._fall_back(text, f"the LLM did not answer within {self.timeout:g} s")
        except urllib.error.HTTPError as error:
            if 300 <= error.code < 400:  # the API key would go along (issue 39)
                where = error.headers.get("Location")
                return self._fall_back(
                    text,
                    f"the LLM server answered HTTP {error.code}, a "
                    f"redirect to {where!r}, not followed",
                )
            return self._fall_back(text, f"the LLM server answered HTTP {error.code}")
        except http.client.IncompleteRead:
            return self._fall_back(text, "the LLM server's reply was cut short")
        except http.client.HTTPException as error:
            return self._fall_back(
                text, f"the LLM server's reply was not HTTP ({type(error).__name__})"
            )
        except (urllib.error.URLError, OSError) as error:
            reason = getattr(error, "reason", error)
            if isinstance(reason, TimeoutError):
                return self._fall_back(text, f"the LLM did not answer within {self.timeout:g} s")
            return self._fall_back(text, f"cannot reach the LLM server at {self.url}: {reason}")
        except ValueError as error:
            return self._fall_back(text, f"the LLM server's reply was not usable: {error}")
        try:
            steps = checked_steps(last_json_object(content))
        except ValueError as error:
            return self._fall_back(text, f"the LLM answer {error}")
        return Alignment(steps, "llm")

    def messages(self, text: str) -> list[dict]:
        """The chat: instructions, the worked examples, then the user's prompt."""
        chat = [dict(role="system", content=SYSTEM_PROMPT)]
        for question, answer in EXAMPLES:
            chat += [dict(role="user", content=question), dict(role="assistant", content=answer)]
        return chat + [dict(role="user", content=text)]

    def _ask(self, text: str) -> str:
        body = json.dumps(
            dict(model=self.model, messages=self.messages(text), temperature=0, stream=False)
        ).encode()
        headers = {"Content-Type": "application/json"}
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        request = urllib.request.Request(
            self.url.rstrip("/") + "/chat/completions", body, headers, method="POST"
        )
        watchdog = _Watchdog(self.timeout)
        opener = urllib.request.build_opener(
            _NoRedirect, watchdog.handler(_HTTP), watchdog.handler(_HTTPS)
        )
        try:
            with watchdog, opener.open(request, timeout=self.timeout) as response:
                data = response.read(MAX_REPLY_BYTES + 1)
                missing = response.length  # of its Content-Length (a read cut short)
        except (OSError, http.client.HTTPException):
            if watchdog.expired:
                raise TimeoutError from None
            raise
        if watchdog.expired:
            raise TimeoutError
        if missing and len(data) <= MAX_REPLY_BYTES:
            raise http.client.IncompleteRead(data, missing)
        if len(data) > MAX_REPLY_BYTES:
            raise ValueError(f"it is larger than {MAX_REPLY_BYTES} bytes")
        try:
            reply = json.loads(data.decode("utf-8"))
        except RecursionError:
            raise ValueError("its JSON is nested too deeply") from None
        try:
            return reply["choices"][0]["message"]["content"]
        except (KeyError, IndexError, TypeError):
            raise ValueError("no choices[0].message.content in it") from None

    def _fall_back(self, text: str, why: str) -> Alignment:
        alignment = self.fallback.align(text)
        note = f"{why}; used the rules" + (f" ({alignment.note})" if alignment.note else "")
        return Alignment(alignment.steps, alignment.source, note)


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """A redirect is an HTTPError: the request and its API key go nowhere else."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        return None


class _Watchdog:
    """Shuts the connection's socket once `timeout` seconds have passed since it started,
    whatever phase the exchange is in (a server may drip its reply a byte a second)."""

    def __init__(self, timeout: float):
        self.timer = threading.Timer(timeout, self._expire)
        self.timer.daemon = True
        self.sockets, self.expired, self.lock = [], False, threading.Lock()

    def handler(self, base: type) -> urllib.request.BaseHandler:
        """`base` (a handler below) whose connections this watchdog watches."""
        handler = base()
        handler.watchdog = self
        return handler

    def watch(self, sock: socket.socket) -> None:
        with self.lock:
            self.sockets.append(sock)
            if self.expired:
                _shut(sock)

    def _expire(self) -> None:
        with self.lock:
            self.expired = True
            for sock in self.sockets:
                _shut(sock)

    def __enter__(self):
        self.timer.start()
        return self

    def __exit__(self, *exc) -> None:
        self.timer.cancel()


def _shut(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)  # a read blocked on it returns at once
    except OSError:
        pass


class _Watched:
    """A urllib handler whose connections tell their socket to a _Watchdog."""

    watchdog: _Watchdog

    def do_open(self, http_class, req, **kwargs):
        watchdog = self.watchdog

        class Connection(http_class):
            def connect(self):
                super().connect()
                watchdog.watch(self.sock)

        return super().do_open(Connection, req, **kwargs)


class _HTTP(_Watched, urllib.request.HTTPHandler):
    pass


class _HTTPS(_Watched, urllib.request.HTTPSHandler):
    pass


def last_json_object(content: str) -> dict:
    """The last {...} block of a reply that may think aloud before answering."""
    content = content[-MAX_ANSWER_CHARS:]  # each "{" is tried: the work grows as its square
    end = content.rfind("}")
    start = content.rfind("{", 0, end)
    while start >= 0:
        try:
            value = json.loads(content[start : end + 1])
        except (json.JSONDecodeError, RecursionError):
            start = content.rfind("{", 0, start)
            continue
        if isinstance(value, dict):
            return value
        break
    raise ValueError("was not valid JSON")


def checked_steps(answer: dict) -> tuple[AlignedStep, ...]:
    """The schema {"prompt": str, "steps": [{"prompt": str, "seconds": 0.5..30}, 1..8]}."""
    steps = answer.get("steps")
    if not isinstance(answer.get("prompt"), str) or not isinstance(steps, list):
        raise ValueError("does not match the schema: it needs 'prompt' (text) and 'steps' (a list)")
    if not 1 <= len(steps) <= MAX_STEPS:
        raise ValueError(f"has {len(steps)} steps; 1 to {MAX_STEPS} are allowed")
    checked = []
    for k, step in enumerate(steps):
        prompt = step.get("prompt") if isinstance(step, dict) else None
        seconds = step.get("seconds") if isinstance(step, dict) else None
        if not isinstance(prompt, str) or not prompt.strip():
            raise ValueError(f"step {k + 1} has no prompt text")
        if (
            isinstance(seconds, bool)
            or not isinstance(seconds, (int, float))
            or not (STEP_SECONDS[0] <= seconds <= STEP_SECONDS[1])
        ):
            raise ValueError(
                f"step {k + 1} has seconds {seconds!r}; a number from "
                f"{STEP_SECONDS[0]} to {STEP_SECONDS[1]:g} is needed"
            )
        checked.append(AlignedStep(prompt.strip(), float(seconds)))
    return tuple(checked)
