"""A camera's credentials kept out of every message (pure).

FFmpeg's and PyAV's errors end with the URL they opened (`... 401 Unauthorized: 'rtsp://admin:pw@host/cam'`), and a
URL may come back in other forms (percent-encoded or not, the user and password alone). Every text that can carry
one goes through `redact` before a log line, an event or a page: each URL's user and password, and each form of the
camera's own secrets, become `***`.
"""

from __future__ import annotations

import re
from urllib.parse import quote, unquote, urlsplit

HIDDEN = "***"
# scheme://USERINFO@ in any text: a user and password of any URL (the characters RFC 3986 allows before the '@')
URL_USERINFO = re.compile(r"(?i)\b([a-z][a-z0-9+.\-]*://)[^\s'\"/?#@]*@")


def secrets_of(url: str) -> tuple[str, ...]:
    """The forms a URL's password (and its user:password) may take in a message, longest first."""
    netloc = urlsplit(url).netloc
    userinfo = netloc.rpartition("@")[0]
    if not userinfo:
        return ()
    password = userinfo.partition(":")[2]
    forms = {userinfo, unquote(userinfo), password, unquote(password), quote(unquote(password), safe="")}
    return tuple(sorted((f for f in forms if f), key=len, reverse=True))


def redact(text: str, secrets: tuple[str, ...] = ()) -> str:
    """`text` without any URL's user and password and without any of `secrets`."""
    for secret in secrets:  # first: a decoded password may hold the '@' or '/' the pattern below stops at
        text = text.replace(secret, HIDDEN)
    return URL_USERINFO.sub(lambda m: m.group(1) + HIDDEN + "@", text)


def redact_camera(text: str, url: str) -> str:
    """`text` (FFmpeg's error, an exception) without the camera `url`'s credentials in any form, nor any URL's."""
    return redact(text, secrets_of(url))
