"""Reports for people: the session report and the diagnosis report (HTML with figures)."""
