"""The learned subject: a small language-conditioned policy trained on the scripted expert's demonstrations."""
