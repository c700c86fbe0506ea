"""Host-side codecs: encode what the host sends, parse what the printer says. Sans-IO."""
