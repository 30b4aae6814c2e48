"""`usb2rc web`: a page for the headless Pi, fed by the daemon's status socket.

`feed` reads the socket (and reconnects when the daemon restarts), `server` serves the page,
`GET /api/status` and the live stream (server-sent events); the page itself is package data
in `static/` (no CDN: the field has no internet)."""
