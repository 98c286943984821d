"""Rendering of results: tables (:mod:`.tables`), figures (:mod:`.plots`) and report files.

Nothing here computes a fit; these modules only turn arrays and result objects into files a person
reads.
"""
