"""Diagnosis: which physical effect is missing from a fitted law (score tests at the effect's
null value, from one forward solve with sensitivities), and the loop that adds it."""
