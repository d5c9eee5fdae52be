"""gazepipe: capture sessions in, validated training sets for gaze and facial animation out."""

__version__ = "0.1.0"
