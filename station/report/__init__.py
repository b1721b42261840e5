"""Reports for people: the session report and the diagnosis report, both self-contained HTML
pages with figures built by the one page builder (html.py)."""
