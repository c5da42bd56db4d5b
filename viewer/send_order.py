"""Every edit and click in the panel reaches the server, in the order it was made.

viser's page sends a panel's messages (a field's new text, a ticked box, a click) through a throttle
(one per panel: the main one, each docked panel, each window): the first message of a 50 ms window
goes at once, the last one after it waits for the window's end, and each later one *replaces* the
waiting one. So of three quick actions ("type the joint positions, type a label, click Add": a
script, or a fast hand) the middle one never reaches the server, and the server acts on a value the
page no longer shows. Even a message left waiting alone can be lost: the throttle forgets it when its
panel is drawn anew, or the link is down, when the window ends (a click that so never arrived was
seen once in 20 runs of the use case's browser test).

The page here keeps a copy of the throttles' state (as one: a panel's window open counts for all).
A field's text may wait for the window's end and replace its own waiting text (the latest wins, and
holding the keys of a field being typed in would let the page draw its old text back under the next
key); anything else that would have to wait, or replace another field's text, is held back and
replayed once the window has ended, when it goes at once (a field's held edits replay as one, with
the text the field then holds, and its keys and its leaving after them; a held box shows its tick at
once). So a click is never left waiting. Nothing is held outside a window, so a lone click or a
typed field goes as before; a quick second action waits at most a window. Not covered: a hold
button's repeats and a slider's drag (they stream; the next one carries the state) and a dropdown
picked with the keyboard.
"""

from __future__ import annotations

from typing import Any

from .browser import run_js

#: viser's panel throttle (its ``useThrottledMessageSender(50)``).
THROTTLE_MS = 50

SEND_ORDER_JS = """(() => {
  if (window.__simecsSendOrder) return;
  window.__simecsSendOrder = true;
  const WINDOW_MS = __WINDOW_MS__;
  // The throttle: `open` while a window runs, `waiting` the field whose text it keeps for the window's
  // end (null: none). Every message the page sends leaves through the worker that holds its websocket:
  // each one seen there opens a window (ours, and those viser sends of itself, which no event here
  // shows: a number box echoing the value the server set it to), and nothing waits right after it (it
  // was sent at once, or it was the waiting one). Our copy of the window's timer is set once the task
  // that set viser's has ended (a 0 ms timer first), with the same delay: it fires after viser's,
  // however late timers run and however long viser took, so a message replayed then goes at once.
  let open = false, waiting = null, replaying = false, windows = 0;
  const held = [], sent = window.__simecsSent = [];
  const windowEnds = () => {
    const mine = ++windows;
    setTimeout(() => setTimeout(() => {
      if (mine !== windows) return;  // a later message opened a later window
      open = false;
      waiting = null;
      release();
    }, WINDOW_MS), 0);
  };
  // The panels' messages only (Gui…): the camera's go through a throttle of their own.
  const post = Worker.prototype.postMessage;
  Worker.prototype.postMessage = function (data, ...rest) {
    const type = data && data.type === 'send' && data.message ? String(data.message.type) : '';
    if (type.startsWith('Gui')) {
      // the last panel messages sent, for a failed browser test to keep (what left the page, when)
      const updates = JSON.stringify(data.message.updates || '').slice(0, 60);
      sent.push([Math.round(performance.now()), type, String(data.message.uuid || ''), updates]);
      if (sent.length > 40) sent.shift();
      open = true;
      waiting = null;
      windowEnds();
    }
    return post.call(this, data, ...rest);
  };
  // Only a field's text may wait, and replace its own waiting text (the latest wins): held instead, the
  // field would be drawn back to the text the page knows under the user's next key. A click or a box
  // in a window is held, never left waiting.
  const admit = (key, kind) => {  // true: viser's throttle takes it without dropping another
    if (!open) return true;  // it goes at once (and its message, seen leaving, opens the window)
    if (kind === 'input' && (waiting === null || waiting === key)) { waiting = key; return true; }
    return false;
  };
  const release = () => {  // in the order made; a relayed event (no message of its own) in its turn
    while (held.length && (held[0].kind === 'relay' || admit(held[0].key, held[0].kind))) {
      const h = held.shift();
      console.debug(`simecs send order: replays a ${h.kind} (${describe(h.el)})`);
      replaying = true;
      try { h.kind === 'input' ? retype(h) : h.replay(); } finally { replaying = false; }
    }
  };
  const gate = (e, el, key, kind, replay) => {
    if (replaying) return;
    if (!held.length && admit(key, kind)) return;
    e.stopImmediatePropagation();  // the page's own handlers (viser's) see it when it is replayed
    if (kind === 'click') e.preventDefault();
    const same = kind !== 'click' && held.find((h) => h.el === el && h.kind === kind);
    if (same) {  // one replay, with the latest text
      same.text = el.value;
      return;
    }
    held.push({el, key, kind, replay, text: el.value});
    console.debug(`simecs send order: holds a ${kind} (${describe(el)}) to the window's end`);
  };
  // For the page's console (a failed browser test keeps it): which element a hold or replay was.
  const describe = (el) => `${el.tagName.toLowerCase()} "${(el.textContent || el.value || '').slice(0, 30)}"`;
  // A held edit's text is kept: the widget may be drawn again meanwhile (a vector's other box heard
  // first), which writes back into the field the value viser knows.
  const retype = (h) => {  // the prototype's setter: React's own on the element would hide the change
    const setText = Object.getOwnPropertyDescriptor(Object.getPrototypeOf(h.el), 'value').set;
    if (h.el.value !== h.text) setText.call(h.el, h.text);
    h.el.dispatchEvent(new Event('input', {bubbles: true}));
  };
  // A held click's element may be drawn anew before its replay (its panel re-rendered): the replay
  // then clicks the element now in its place, the same kind with the same label at the same rank.
  const findAgain = (el) => {
    const selector = el.matches('button') ? 'button' : '[role=option]';
    const label = el.textContent;
    const rank = [...document.querySelectorAll(selector)].filter((b) => b.textContent === label).indexOf(el);
    return () => [...document.querySelectorAll(selector)].filter((b) => b.textContent === label)[rank];
  };
  const typedField = (el) =>
    (el instanceof HTMLInputElement && !['checkbox', 'radio', 'file'].includes(el.type)) ||
    el instanceof HTMLTextAreaElement;
  window.addEventListener('click', (e) => {
    const t = e.target instanceof Element ? e.target : null;
    if (t instanceof HTMLInputElement && t.type === 'checkbox') {
      // The box ticks at once (the browser's own toggle is let be); viser hears of it on replay: the
      // box is set back and clicked, so it ends as the user left it.
      gate(e, t, t, 'box', () => { const want = t.checked; t.checked = !want; t.click(); });
      return;
    }
    const el = t && t.closest('button, [role=option]');
    // A notification's close button sends viser nothing: counted, it would hold the next real click.
    if (el && !el.closest('.mantine-Notification-root')) {
      const again = findAgain(el);
      gate(e, el, null, 'click', () => (el.isConnected ? el : again() || el).click());
    }
  }, true);
  window.addEventListener('input', (e) => {
    const el = e.target;
    // A field's key is its viser widget (a vector's boxes are one widget, one message of all its values).
    if (typedField(el)) gate(e, el, el.closest('.mantine-Flex-root') || el, 'input', null);
  }, true);
  // While a field's edit is held, its keys, its change and its leaving wait behind it: a number
  // field would otherwise write back, on Enter or on leaving, the value it has not heard of yet.
  for (const type of ['keydown', 'keyup', 'change', 'focusout']) {
    window.addEventListener(type, (e) => {
      const el = e.target;
      if (replaying || !typedField(el) || !held.some((h) => h.el === el && h.kind === 'input')) return;
      e.stopImmediatePropagation();
      if (type === 'change') return;  // the edit's replay tells viser the value
      const again = type === 'focusout'
        ? new FocusEvent('focusout', {bubbles: true, relatedTarget: e.relatedTarget})
        : new KeyboardEvent(type, {key: e.key, code: e.code, bubbles: true, cancelable: true,
            shiftKey: e.shiftKey, ctrlKey: e.ctrlKey, altKey: e.altKey, metaKey: e.metaKey});
      held.push({el, key: null, kind: 'relay', replay: () => el.dispatchEvent(again)});
    }, true);
  }
})();""".replace("__WINDOW_MS__", str(THROTTLE_MS))


def install_send_order(client: Any) -> None:
    """Hold back, on this tab's page, what would replace a message viser still keeps waiting."""
    run_js(client, SEND_ORDER_JS)
