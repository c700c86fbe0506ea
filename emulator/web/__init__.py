"""The live view (`fake-marlin --web [HOST:]PORT`): a farm's printers on a web page, live.

snapshot.py reads a printer into JSON-able rows and details; source.py is where the view gets
them (LocalFarm: this process's printers; FarmSource: what any source provides); pages.py the
HTML, style and script; app.py the ASGI app on hypercorn's trio worker (serve_web).
docs/web.md says what the pages show and what they cost.
"""
