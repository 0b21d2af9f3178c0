"""The LLM aligner against hostile or broken chat servers on 127.0.0.1 (real sockets): the API
key never follows a redirect, --llm-timeout bounds the whole reply, a reply cut short, too
large or nested too deeply is one note and the rules answer. Bounded in time."""

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from mogo.llm_align import MAX_REPLY_BYTES, LLMAligner

ANSWER = json.dumps(
    {
        "choices": [
            {
                "message": {
                    "content": json.dumps(
                        {
                            "prompt": "a person walks.",
                            "steps": [{"prompt": "a person walks.", "seconds": 2}],
                        }
                    )
                }
            }
        ]
    }
)


@pytest.fixture
def serve():
    """serve(do_post, do_get=None) -> the base URL of a server on an ephemeral port."""
    servers = []

    def start(post, get=None):
        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                post(self)

            def do_GET(self):
                (get or post)(self)

        server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        server.daemon_threads = True
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_port}"

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


def test_the_api_key_never_follows_a_redirect(serve):
    seen = []

    def steal(handler):
        seen.append(handler.headers.get("Authorization"))
        handler.send_response(200)
        handler.send_header("Content-Length", str(len(ANSWER)))
        handler.end_headers()
        handler.wfile.write(ANSWER.encode())

    thief = serve(steal)

    def redirect(handler):
        handler.send_response(307)  # 307 keeps the POST and its body
        handler.send_header("Location", thief + "/v1/chat/completions")
        handler.end_headers()

    alignment = LLMAligner(serve(redirect) + "/v1", api_key="sk-SECRET").align("walk")
    assert seen == []
    assert alignment.source == "rules"
    assert alignment.note.startswith(
        f"the LLM server answered HTTP 307, a redirect to "
        f"'{thief}/v1/chat/completions', not followed; used the "
        "rules"
    )


def test_the_timeout_bounds_a_reply_dripped_a_byte_at_a_time(serve):
    def drip(handler):
        handler.send_response(200)
        handler.send_header("Content-Length", str(len(ANSWER)))
        handler.end_headers()
        for byte in ANSWER.encode():
            try:
                handler.wfile.write(bytes([byte]))
                handler.wfile.flush()
            except OSError:
                return
            time.sleep(0.1)  # 30 s for the whole answer

    started = time.monotonic()
    alignment = LLMAligner(serve(drip) + "/v1", timeout=1.0).align("walk")
    assert alignment.note.startswith("the LLM did not answer within 1 s; used the rules")
    assert time.monotonic() - started < 20  # a bound, not a speed: the drip takes 30 s


@pytest.mark.parametrize(
    "reply, note",
    [
        (ANSWER.encode()[:40], "the LLM server's reply was cut short"),
        (b" " * (MAX_REPLY_BYTES + 10), f"larger than {MAX_REPLY_BYTES} bytes"),
        (b"[" * 100_000, "nested too deeply"),
        (
            json.dumps({"choices": [{"message": {"content": "{" * 200_000 + "x}"}}]}).encode(),
            "the LLM answer was not valid JSON",
        ),
    ],
)
def test_a_broken_reply_is_one_note(serve, reply, note):
    def answer(handler):
        handler.send_response(200)
        handler.send_header("Content-Length", str(len(ANSWER) if len(reply) < 50 else len(reply)))
        handler.end_headers()
        handler.wfile.write(reply)
        handler.wfile.flush()
        handler.close_connection = True

    alignment = LLMAligner(serve(answer) + "/v1", timeout=30).align("walk")
    assert alignment.source == "rules" and note in alignment.note
