"""The application: the command line (``rollbot-oc``) and the demo report."""
