"""The paper's study and our additions: experiments, figures and the report."""
