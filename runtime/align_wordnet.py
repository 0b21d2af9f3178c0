"""Verbs by the primitive they ask for, from WordNet 3.0 (generated: do not edit).
Regenerate with
`python -m mogo.export.data.wordnet_synonyms --out runtime/align_wordnet.py \
    --people-out export/data/wordnet_people.py`
(mogo.export.data.wordnet_synonyms says how)."""
# WordNet Release 3.0. This software and database is being provided to you, the LICENSEE,
# by Princeton University under the following license. By obtaining, using and/or copying
# this software and database, you agree that you have read, understood, and will comply with
# these terms and conditions.: Permission to use, copy, modify and distribute this software
# and database and its documentation for any purpose and without fee or royalty is hereby
# granted, provided that you agree to comply with the following copyright notice and
# statements, including the disclaimer, and that the same appear on ALL copies of the
# software, database and documentation, including modifications that you make for internal
# use or for distribution. WordNet 3.0 Copyright 2006 by Princeton University. All rights
# reserved. THIS SOFTWARE AND DATABASE IS PROVIDED "AS IS" AND PRINCETON UNIVERSITY MAKES NO
# REPRESENTATIONS OR WARRANTIES, EXPRESS OR IMPLIED. BY WAY OF EXAMPLE, BUT NOT LIMITATION,
# PRINCETON UNIVERSITY MAKES NO REPRESENTATIONS OR WARRANTIES OF MERCHANT- ABILITY OR FITNESS
# FOR ANY PARTICULAR PURPOSE OR THAT THE USE OF THE LICENSED SOFTWARE, DATABASE OR
# DOCUMENTATION WILL NOT INFRINGE ANY THIRD PARTY PATENTS, COPYRIGHTS, TRADEMARKS OR OTHER
# RIGHTS. The name of Princeton University or Princeton may not be used in advertising or
# publicity pertaining to distribution of the software and/or database. Title to copyright
# in this software, database and any associated documentation shall at all times remain with
# Princeton University and LICENSEE agrees to preserve same.

WORDNET_VERBS = {
    'walk': ('ambulate', 'backpack', 'bumble', 'careen', 'clomp', 'coggle', 'countermarch', 'debouch', 'dodder', 'flounce', 'flounder', 'foot', 'footslog', 'gimp', 'hobble', 'hoof', 'keel', 'limp', 'lollop', 'lumber', 'lurch', 'mosey', 'mouse', 'perambulate', 'plod', 'prance', 'process', 'promenade', 'prowl', 'puddle', 'pussyfoot', 'reel', 'scuff', 'scuffle', 'shamble', 'shlep', 'skulk', 'sleepwalk', 'slink', 'slog', 'slosh', 'sneak', 'somnambulate', 'spacewalk', 'splosh', 'squelch', 'squish', 'stagger', 'stalk', 'stamp', 'stomp', 'strut', 'stumble', 'stump', 'swagger', 'tippytoe', 'tittup', 'toddle', 'toe', 'traipse', 'tramp', 'trample', 'treadle', 'troop', 'trudge', 'waddle', 'wade'),
    'run': ('barge', 'buck', 'hare', 'hasten', 'hie', 'hotfoot', 'lope', 'outrun', 'scamper', 'scoot', 'scud', 'scurry', 'scuttle', 'skitter', 'speed'),
    'jump': ('bounce', 'burst', 'caper', 'capriole', 'carom', 'curvet', 'galumph', 'hurdle', 'leapfrog', 'overleap', 'pronk', 'rebound', 'resile', 'reverberate', 'ricochet', 'vault'),
    'spin': ('whirligig',),
    'squat': ('hunker', 'scrunch'),
    'sit': ('lounge', 'perch', 'roost', 'sprawl'),
    'bow': ('conge', 'curtsey', 'curtsy', 'genuflect', 'kowtow'),
    'wave': ('beckon',),
    'raise_arms': ('elevate',),
    'clap': ('bravo',),
    'kick': ('boot', 'dropkick', 'punt'),
}
