"""mkdocs hook: the docstrings' Sphinx roles (:func:`~peeljax.x.y`) read as code on the site.

The docstrings keep Sphinx's roles, which ``help()`` shows as they are; mkdocstrings renders the
role's name as text before the code (":func:<code>~peeljax.x.y</code>"). This drops the role
and the "~" (Sphinx's "show the last component only"), keeping the name as code.
"""

import re

ROLE = re.compile(r":(?:func|class|meth|mod|data|attr|exc|obj):<code>~?([^<]*)</code>")


def on_page_content(html, page, config, files):
    def name(match):
        path = match.group(1)
        return f"<code>{path.rsplit('.', 1)[-1] if match.group(0).find('~') >= 0 else path}</code>"

    return ROLE.sub(name, html)
