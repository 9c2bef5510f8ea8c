"""`micam web`: the operator's page, a client of the daemon's ZeroMQ protocol like the CLI.

- `view`: what the page shows, made from the daemon's messages (pure functions, tested alone);
- `bridge`: the one connection to the daemon (events, status polls, preview requests) and the
  fan-out of every event to the connected browsers;
- `access`: who may open the page (loopback by default, a token otherwise); `hosts`: the
  names it answers to (against DNS rebinding); `guard`: the middleware applying both;
- `limits`, `server`: request bodies and heads bounded in size and time (the middleware, and
  uvicorn's protocol and options); `json_body`: JSON from outside, read within bounds;
  `refusals`: every refusal as a status, a code and a reason;
- `app`: the Starlette application (the page, its WebSocket, its commands), run by uvicorn.

It holds no private path into the daemon: it may run on another machine, and killing it never
touches a capture (docs/operator.md).
"""
