"""The word lists of the prompt-alignment rules (mogo.align.RuleAligner): verbs by the
primitive they ask for, nouns, typical step durations, synonyms, number words (and how the
captions spell a number), and the subjects, fillers and hedges the rules drop. Data, and the
number speller every reader of prompts shares; the rules are in mogo.align."""
from __future__ import annotations

import re

# Verbs by the primitive they ask for. The corpus's own verbs come first; the rest are
# synonyms, replaced by the first verb of their primitive when the bundle does not know them.
VERBS = {
    "walk": ("walk", "stroll", "stride", "sidestep", "step", "shuffle", "march", "amble",
             "wander", "saunter", "tiptoe", "pace", "move", "head", "go", "back", "cover"),
    "jog": ("jog", "trot"),
    "run": ("run", "sprint", "dash", "race", "rush", "hurry"),
    "turn": ("turn", "rotate", "pivot", "swivel"),
    "spin": ("spin", "twirl", "whirl", "pirouette"),
    "jump": ("jump", "hop", "leap", "bound", "spring", "skip"),
    "squat": ("squat", "crouch", "duck"),
    "sit": ("sit", "settle"),
    "bow": ("bow", "lean"),
    "wave": ("wave",),
    "raise_arms": ("raise", "lift", "reach", "put"),
    "clap": ("clap", "applaud"),
    "punch": ("punch", "jab", "strike", "hit", "box", "throw"),
    "kick": ("kick", "swing"),
    "stretch": ("stretch", "limber"),
    "idle": ("stand", "wait", "stay", "pause", "remain", "rest", "idle", "freeze", "stop"),
    # No primitive of their own: the step's nouns tell, or the model does not know it.
    None: ("do", "perform", "take", "give", "make", "bend", "lower", "come", "rise", "bring",
           "close", "spread", "get", "begin", "start", "finish", "keep", "try", "dance",
           "kneel", "crawl", "roll", "climb", "swim", "push", "pull", "pick", "carry", "fall",
           "fly", "catch", "drink", "eat", "flip", "somersault", "cartwheel", "backflip"),
}
# Nouns that name the primitive when the verb does not ("does three squats").
NOUNS = {"jack": "jumping_jacks", "jacks": "jumping_jacks", "squat": "squat",
         "squats": "squat", "clap": "clap", "claps": "clap", "punch": "punch",
         "punches": "punch", "kick": "kick", "kicks": "kick", "bow": "bow", "seat": "sit",
         "chair": "sit", "stretch": "stretch", "spin": "spin",
         "jump": "jump", "jumps": "jump", "wave": "wave", "turn": "turn", "jog": "jog"}
# Seconds a step takes: fixed, or (base, per repetition), from the corpus's segment lengths.
SECONDS = {"walk": 3.3, "jog": 3.0, "run": 2.7, "turn": 2.2, "spin": 2.0, "sit": 3.8,
           "bow": 2.0, "raise_arms": 2.3, "kick": 2.0, "stretch": 3.6, "idle": 2.0,
           "squat": (0.9, 0.9), "clap": (1.6, 0.2), "jumping_jacks": (1.1, 0.8),
           "jump": (1.3, 0.6), "punch": (1.8, 0.15), "wave": (1.5, 0.5), None: 3.0}
WORD_SYNONYMS = {"fwd": "forward", "forwards": "forward", "ahead": "forward",
                 "backwards": "backward", "back": "backward", "leftwards": "leftward",
                 "rightwards": "rightward", "anticlockwise": "counterclockwise",
                 "your": "their", "my": "their", "our": "their", "palm": "hand",
                 "palms": "hands", "fists": "fist", "hi": "hello", "bye": "hello",
                 "goodbye": "hello", "rapid": "quick", "rapidly": "quickly",
                 "gently": "slowly", "chairs": "chair"}
# Phrases the captions write otherwise (caption_phrases).
PHRASES = {"star jumps": "jumping jacks", "star jump": "jumping jack",
           "counter clockwise": "counterclockwise", "anti clockwise": "counterclockwise"}
# The words between the steps of a sequence ("walk, then jump"; "after X, Y" apart).
SEQUENCE = re.compile(
    r",?\s*\b(?:and then|and afterwards|and after that|after that|afterwards|after which|"
    r"(?:and )?(?:when|once) (?:that'?s |that is |it'?s |it is )?(?:done|finished|over)|"
    r"and finally|finally|lastly|"
    r"and next|next|followed by|subsequently|then|before)\b,?\s*")
NUMBERS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine",
           "ten", "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen",
           "eighteen", "nineteen")
TENS = ("", "", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety")
SUBJECTS = ("a person", "the person", "a man", "the man", "a woman", "the woman", "someone",
            "somebody", "the guy", "a guy", "the dude", "a dude", "the girl", "a girl",
            "the boy", "a boy", "the kid", "a kid", "the character", "a character",
            "my character", "the figure", "a figure", "the avatar", "the model", "the actor",
            "he", "she", "they", "him", "her", "them", "it", "you", "we", "i")
FILLERS = ("please", "pls", "can you", "could you", "would you", "will you", "i want",
           "i would like", "id like", "i wanna", "i need", "lets see", "let me see",
           "show me", "show", "to see", "want to see", "generate", "animate", "create",
           "a motion where", "a motion of", "an animation of", "an animation where",
           "motion of", "now", "and", "so", "ok", "okay", "first", "firstly", "then", "also",
           "just", "um", "uh", "like", "kinda", "maybe", "kind of", "sort of", "try to",
           "starts by", "start by", "begins by",
           "begin by", "to", "should", "will", "must", "can", "is", "are", "needs to",
           "has to", "have to", "is going to", "going to", "gonna")
# Hedges dropped wherever they are ("walk forward a bit, like maybe four steps").
HEDGES = ("um", "uh", "like", "maybe", "kinda", "just", "really", "basically", "actually",
          "please", "a bit", "a little bit", "sort of", "kind of")
CAUSATIVES = ("make", "have", "let", "get", "want", "tell", "ask")
# Ordinary words the typo fixer must leave alone ("wall" is not a typo of "walk").
LEFT_ALONE = ("a", "an", "the", "of", "and", "or", "in", "on", "at", "to", "with", "by",
                  "for", "from", "up", "down", "out", "into", "onto", "over", "around",
                  "while", "as", "his", "her", "their", "its", "it", "this", "that", "few",
                  "some", "times", "time", "once", "twice", "again", "very", "really", "bit",
                  "little", "seconds", "second", "same", "like", "then", "both", "left",
                  "right", "hand", "hands", "arm", "arms", "leg", "legs", "foot", "head",
                  "body", "floor", "ground", "air", "place", "guy", "man", "woman", "person",
                  "character", "someone", "somebody", "you", "your", "me", "we", "they",
                  "toward", "towards", "across", "away", "wall", "door", "room", "table", "ball",
                  "stairs", "street", "friend", "music", "there", "here", "where", "what",
                  "when", "how", "something", "thing", "way", "long", "short", "high", "low",
                  "happy", "happily", "sad", "angry", "angrily", "tired", "excited", "quietly",
                  "carefully", "casually", "lot", "world", "sideways", "slowly", "quickly",
                  "fast", "slow", "circle", "still", "seat", "together", "clockwise",
                  "degrees", "politely", "steps", "strides", "done", "finished", "over",
                  "yoga", "salsa", "pushups", "situps")


def spoken_number(n: int) -> str:
    """0-999 as the corpus's captions write them: "seven", "forty-five", "a hundred and
    thirty-five", "three hundred and sixty"; other numbers as digits."""
    if not 0 <= n < 1000:
        return str(n)
    if n < 20:
        return NUMBERS[n]
    if n < 100:
        return TENS[n // 10] + ("" if n % 10 == 0 else "-" + NUMBERS[n % 10])
    hundreds = "a hundred" if n < 200 else f"{NUMBERS[n // 100]} hundred"
    return hundreds + ("" if n % 100 == 0 else " and " + spoken_number(n % 100))


_NUMBER = re.compile(r"(?<![\w.,])(\d+)(?![\w]|[.,]\d)(\s+times?\b)?")


def spoken_numbers(text: str) -> str:
    """Whole numbers in a prompt spelt as the captions spell them, which is how the model
    learnt them: "turns 90 degrees" -> "turns ninety degrees", "2 times" -> "twice"."""
    def spell(match: re.Match) -> str:
        n, times = int(match.group(1)), match.group(2)
        if times and n in (1, 2):
            return "once" if n == 1 else "twice"
        return spoken_number(n) + (times or "")
    return _NUMBER.sub(spell, text)


_PHRASE = re.compile(rf"\b(?:{'|'.join(PHRASES)})\b", re.IGNORECASE)


def caption_phrases(text: str) -> str:
    """A prompt with its PHRASES as the captions write them ("star jumps" -> "jumping jacks"),
    for the readers of what it says: the rules and the repertoire. (The encoders do not get
    it: the prompts so rewritten played worse than their own words, docs/text_encoder.md.)"""
    return _PHRASE.sub(lambda match: PHRASES[match[0].lower()], text)
