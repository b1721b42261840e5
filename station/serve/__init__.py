"""`station serve`: the technician's station in a browser (docs/serve.md).

- `operator`: the technician at the browser (`BrowserOperator`, the protocols' prompt / wait /
  confirm answered by a click);
- `watch`: what a running session shows (`BrowserView`, the live view's state as JSON);
- `session`: one session per bench at a time, started, paused, resumed and aborted from any
  browser (`BenchSession`), with the very protocol code `station record` and `station resume` run;
- `devices`: the bench's devices before a session (the page's "Check devices");
- `app`: the web application (Starlette): the page, its assets, the live stream (server-sent
  events) and the requests, each checked as untrusted;
- `pages/`: the page, its script and style, served by the station itself.
"""
