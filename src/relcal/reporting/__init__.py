"""Presentation: text tables, JSON documents and the HTML report."""
